"""Run the DIARC (Prolog) version of the rules with SWI-Prolog over recorded steps, to check it against clingo.

DIARC's belief rules are tuProlog; SWI-Prolog reads the same syntax. Each step's beliefs and past-time
operators (as :meth:`RuleEngine.facts` gives them) are asserted, every ``violation/2`` is collected with its
``involves/3`` beliefs, and the facts are retracted again: what DIARC does with one ``assertBeliefs`` and one
``retractBeliefs`` call per step. One ``swipl`` process runs a whole episode.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

from vlaprobe.cognition.solver import TEMPORAL, TYPES, shipped_rules
from vlaprobe.cognition.terms import canonical_name, diarc_name
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols.vocabulary import PREDICATES

_TERM = re.compile(r"([a-z][A-Za-z0-9_]*)\(([^()]*)\)")
_BELIEFS = {diarc_name(p) for p in PREDICATES}

_DRIVER = """
run :- forall(step(T, Facts), (forall(member(F, Facts), assertz(F)), report(T), forall(member(F, Facts), retract(F)))).
report(T) :- ( setof(I-K, violation(I, K), Vs) -> true ; Vs = [] ),
    forall(member(I-K, Vs), ( findall(B, involves(I, K, B), Bs), format("~w|~w|~w|~w~n", [T, I, K, Bs]) )).
"""


def _beliefs(text: str) -> list[str]:
    """Canonical spelling of every belief term written in ``text``, in order of appearance."""
    return [
        f"{canonical_name(name)}({args.replace(' ', '')})"
        for name, args in _TERM.findall(text)
        if name in _BELIEFS and args
    ]


def prolog_violations(
    steps: Sequence[Sequence[str]],
    type_facts: Sequence[str],
    rules: str | Path | None = None,
    swipl: str = "swipl",
    timeout: float = 120.0,
) -> list[set[tuple[str, frozenset[str]]]]:
    """Per step, the set of (rule id, atoms involved) that the Prolog rules flag, run by SWI-Prolog."""
    exe = shutil.which(swipl)
    if exe is None:
        raise VlaprobeError(f"{swipl} not found; install SWI-Prolog (apt-get install swi-prolog-nox)")
    rules = Path(rules) if rules is not None else shipped_rules("pl")
    preds = sorted({(diarc_name(p), n) for p in PREDICATES for n in (1, 2)})
    dynamic = (
        [f"{n}/{a}" for n, a in preds]
        + [f"{op}/1" for op in TEMPORAL]
        + [f"{n}/{a}" for n, a in TYPES.items()]
    )
    lines = [
        f":- dynamic {', '.join(dynamic)}.",
        ":- style_check(-discontiguous).",  # DIARC's files keep a rule's message beside it; tuProlog never warns
        f":- consult('{rules}').",
    ]
    lines += [f.rstrip(".") + "." for f in type_facts]
    lines += [f"step({t}, [{', '.join(facts)}])." for t, facts in enumerate(steps)]
    with tempfile.TemporaryDirectory() as tmp:
        program = Path(tmp) / "episode.pl"
        program.write_text("\n".join(lines) + "\n" + _DRIVER)
        proc = subprocess.run(
            [exe, "-q", "-g", "run", "-t", "halt", str(program)],
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    if proc.returncode != 0 or "Warning" in proc.stderr or "ERROR" in proc.stderr:
        first = (proc.stderr.strip().splitlines() or ["no output"])[0]
        raise VlaprobeError(f"SWI-Prolog failed on {rules}: {first}")
    out: list[set[tuple[str, frozenset[str]]]] = [set() for _ in steps]
    for line in proc.stdout.splitlines():
        t, rule, key, involved = line.split("|", 3)
        out[int(t)].add((rule, frozenset(_beliefs(key) + _beliefs(involved))))
    return out
