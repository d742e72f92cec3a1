"""The consistency rules, evaluated by clingo (ASP) once per step over the current beliefs and their history.

The program is grounded once: every belief is an ``#external`` atom, and so is each past-time operator
(``prev``, ``ever``, ``recent``) of the beliefs the rules read through it (found by parsing the rules). Each step only the externals whose truth value changed are assigned
(a few per step) and the solver is run again (multi-shot solving); a step with no change reuses the last
answer. Rules files: the shipped ``rules/consistency.lp`` plus any the user adds; a syntax error, an unknown
predicate or a rule without a head stops loading with one line naming the file and line.
"""

from __future__ import annotations

import contextlib
import re
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import clingo
import clingo.ast
import numpy as np

from vlaprobe.cognition.budget import check_budget, check_grounding, read_rules_text, solve_within
from vlaprobe.cognition.plan import TaskGoal
from vlaprobe.cognition.terms import canonical_name, diarc_name, diarc_term
from vlaprobe.configs.monitor import RuleBudget
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols.vocabulary import PREDICATES, parse_atom
from vlaprobe.symbols.world import Goal

ARITY = {
    p: 1 if p in ("on-table", "open", "turned-on", "grasped", "should-move-towards") else 2
    for p in PREDICATES
}
"""Arity of each belief predicate."""
TEMPORAL = ("prev", "ever", "recent")
"""Past-time operators over one belief: held at the previous step, at some step so far, in the last W steps."""
TYPES = {"goal": 2, "object": 1, "pickupable": 1, "container": 1, "part_of": 2}
RESULTS = {"violation": 2, "involves": 3, "message": 2}
_LOCATION = re.compile(
    r"^(?P<file>.*?):(?P<line>\d+):\d+(?:-\d+(?::\d+)?)?: (?P<level>\w+): (?P<text>.*)$", re.S
)


def shipped_rules(kind: str = "lp") -> Path:
    """Path of the shipped rules file: ``"lp"`` (clingo) or ``"pl"`` (DIARC Prolog)."""
    return Path(str(resources.files("vlaprobe.cognition") / "rules" / f"consistency.{kind}"))


@dataclass(frozen=True)
class RuleHit:
    """One instance of a violated rule at one step, as the solver derived it."""

    rule: str
    key: str
    """The rule's instance key as written by the solver (tells instances of one rule apart)."""
    atoms: tuple[str, ...]
    """Canonical spelling of the beliefs involved."""


def _types(atoms: Sequence[str], goal: Goal | TaskGoal) -> list[str]:
    """Facts of the task and the object types, read off the vocabulary's atoms."""
    objects: set[str] = set()
    pick: set[str] = set()
    drawers: set[str] = set()
    for a in atoms:
        pred, args = parse_atom(a)
        if pred in ("grasped", "on", "inside"):
            pick.add(args[0])
        if pred == "open":
            drawers.add(args[-1])
        elif pred not in ("grasped", "turned-on", "inside"):
            objects.update(args)
    pick_place = goal.pick_place if isinstance(goal, TaskGoal) else goal
    # goal(X, Y): the pick-and-place the directive follows; other goals have no directive (labeler)
    facts = [] if pick_place is None else [f"goal({pick_place.pick},{pick_place.place})."]
    facts += [f"object({o})." for o in sorted(objects)]
    facts += [f"pickupable({o})." for o in sorted(pick)]
    facts += [f"container({c})." for c in sorted(drawers)]
    # part_of(C, O): drawer region C belongs to object O (LIBERO names a region <object>_<region>)
    facts += [f"part_of({c},{o})." for c in sorted(drawers) for o in sorted(objects) if c.startswith(f"{o}_")]
    return facts


class _Log:
    """Collects clingo's messages so that the first problem becomes one VlaprobeError line."""

    def __init__(self) -> None:
        self.messages: list[tuple[clingo.MessageCode, str]] = []

    def __call__(self, code: clingo.MessageCode, message: str) -> None:
        self.messages.append((code, message))

    def error(self) -> VlaprobeError | None:
        for code, text in self.messages:
            m = _LOCATION.match(text.strip())
            where = f"{m['file']}:{m['line']}" if m else "rules"
            detail = " ".join((m["text"] if m else text).split())
            if code == clingo.MessageCode.AtomUndefined:
                if m and m["file"] == "<block>":
                    continue
                pred = detail.split(":", 1)[-1].strip()
                return VlaprobeError(
                    f"{where}: unknown predicate in {pred}: no belief, past-time operator ({', '.join(TEMPORAL)}), "
                    f"type ({', '.join(TYPES)}) or rule head has this name and arity; fix the rule"
                )
            if code == clingo.MessageCode.RuntimeError or (m and m["level"] == "error"):
                return VlaprobeError(f"{where}: {detail}; fix the rules file")
        return None


class _Scan(clingo.ast.Transformer):
    """Collects which beliefs the rules look at through a past-time operator: (operator, predicate or None)."""

    def __init__(self) -> None:
        self.uses: set[tuple[str, str | None]] = set()

    def visit_Function(self, node: clingo.ast.AST) -> clingo.ast.AST:
        if node.name in TEMPORAL and len(node.arguments) == 1:
            inner = node.arguments[0]
            named = inner.ast_type == clingo.ast.ASTType.Function and inner.name
            self.uses.add((node.name, inner.name if named else None))  # None: any belief (a variable)
        return node.update(**self.visit_children(node))


def _scan(path: Path) -> set[tuple[str, str | None]]:
    """Check a rules file for rules without a head (``:- body.``: they make the program unsatisfiable instead
    of reporting) and return the beliefs it reads through past-time operators."""
    scan = _Scan()

    def visit(stmt: clingo.ast.AST) -> None:
        scan(stmt)
        if stmt.ast_type != clingo.ast.ASTType.Rule:
            return
        head = stmt.head
        if (
            head.ast_type == clingo.ast.ASTType.Literal
            and head.atom.ast_type == clingo.ast.ASTType.BooleanConstant
        ):
            line = stmt.location.begin.line
            raise VlaprobeError(
                f"{path}:{line}: a rule without a head (':- ...') cannot report a violation; "
                "write violation(Id, Key) :- ... instead"
            )

    with contextlib.suppress(RuntimeError):  # syntax errors: reported with their location when loading
        clingo.ast.parse_files([str(path)], visit, logger=lambda code, msg: None)
    return scan.uses


class RuleEngine:
    """Grounds the rules once over a fixed vocabulary; ``evaluate`` returns the violations of one step."""

    def __init__(
        self,
        atoms: Sequence[str],
        goal: Goal | TaskGoal,
        rules: Sequence[str | Path] = (),
        shipped: bool = True,
        recent_steps: int = 10,
        budget: RuleBudget | None = None,
    ) -> None:
        if recent_steps < 0:
            raise VlaprobeError(f"recent_steps must be >= 0, got {recent_steps}")
        self.atoms = tuple(atoms)
        self.recent_steps = int(recent_steps)
        self.budget = budget or RuleBudget()
        check_budget(self.budget)
        self.users = tuple(Path(p) for p in rules)
        """The user's rules files: grounded first in a child process, solved within the budget."""
        self.files = ([shipped_rules("lp")] if shipped else []) + list(self.users)
        uses: set[tuple[str, str | None]] = set()
        for path in self.files:
            if not path.is_file():
                what = "is a folder" if path.is_dir() else "not found"
                raise VlaprobeError(f"rules file {what}: {path}; pass an existing .lp file to --rules")
            read_rules_text(path)
            uses |= _scan(path)
        for a in self.atoms:
            diarc_term(a)  # every name must be an ASP/Prolog identifier
        terms = [self._symbol(a) for a in self.atoms]
        self._now = terms
        self._ops = {op: [clingo.Function(op, [s]) for s in terms] for op in TEMPORAL}
        parsed = [parse_atom(a) for a in self.atoms]
        # past-time operators only over the beliefs the rules read through them: fewer externals to update
        self._tracked = {
            op: np.array([(op, None) in uses or (op, diarc_name(p)) in uses for p, _ in parsed], dtype=bool)
            for op in TEMPORAL
        }
        known = {(diarc_name(p), len(args)) for p, args in parsed}
        known |= {
            (diarc_name(p), ARITY[p]) for p in PREDICATES
        }  # a scene may lack some (no drawer, no stove)
        known |= {(p, 1) for p in TEMPORAL} | set(TYPES.items()) | set(RESULTS.items())
        self.type_facts: tuple[str, ...] = tuple(_types(self.atoms, goal))
        """The task and type facts (``goal(p,q).``, ``pickupable(o).`` ...) the rules see besides the beliefs."""
        program = list(self.type_facts)
        program += [f"#defined {name}/{n}." for name, n in sorted(known)]
        program += [f"#external {s}." for s in terms]
        program += [
            f"#external {op}({s})."
            for op in TEMPORAL
            for s, on in zip(terms, self._tracked[op], strict=True)
            if on
        ]
        program += ["#show violation/2.", "#show involves/3."]
        if self.users:
            check_grounding("\n".join(program), self.files, self.users, self.budget)
        log = _Log()
        self._ctl = clingo.Control(["--warn=atom-undefined"], logger=log, message_limit=1000)
        self._ctl.add("base", [], "\n".join(program))
        try:
            for path in self.files:
                self._ctl.load(str(path))
            self._ctl.ground([("base", [])])
        except RuntimeError as exc:
            raise log.error() or VlaprobeError(
                f"cannot load the rules {self.files}: {exc}; fix them"
            ) from None
        err = log.error()  # warnings (an undefined atom) do not raise in clingo
        if err is not None:
            raise err
        lookup = self._ctl.symbolic_atoms
        self._lit = {"now": [_literal(lookup, s) for s in self._now]}
        for op in TEMPORAL:  # 0: not tracked (never assigned)
            self._lit[op] = [
                _literal(lookup, s) if on else 0
                for s, on in zip(self._ops[op], self._tracked[op], strict=True)
            ]
        # (program literals of the externals: assigning by literal skips a symbol lookup per call)
        self.messages: dict[str, str] = {}
        for sym in self._ctl.symbolic_atoms.by_signature("message", 2):
            rule, text = sym.symbol.arguments
            self.messages[str(rule)] = text.string if text.type == clingo.SymbolType.String else str(text)
        self._atom_text: dict[clingo.Symbol, str] = {}
        self._parsed: dict[clingo.Symbol, tuple[str, str, list[str]]] = {}
        self._beliefs = {diarc_name(p) for p in PREDICATES}
        self._hits: list[RuleHit] = []
        self.reset()

    @staticmethod
    def _symbol(atom: str) -> clingo.Symbol:
        pred, args = parse_atom(atom)
        return clingo.Function(diarc_name(pred), [clingo.Function(a) for a in args])

    def reset(self) -> None:
        """Forget the history: every external false, nothing pending."""
        n = len(self.atoms)
        self._state = {op: np.zeros(n, dtype=bool) for op in ("now", *TEMPORAL)}
        for lits in self._lit.values():
            for lit in lits:
                if lit:
                    self._ctl.assign_external(lit, False)
        self._last_up = np.zeros(0, dtype=np.int64)
        self._last_down = np.zeros(0, dtype=np.int64)
        self._expiry: dict[int, list[int]] = defaultdict(list)
        self._fell_at = np.full(n, -1, dtype=np.int64)
        self._hits = []
        self._dirty = True

    def _set(self, op: str, index: np.ndarray, value: bool) -> None:
        state = self._state[op]
        index = index[state[index] != value]
        if op != "now":
            index = index[self._tracked[op][index]]
        if index.size == 0:
            return
        state[index] = value
        lits = self._lit[op]
        assign = self._ctl.assign_external
        for i in index.tolist():
            assign(lits[i], value)
        self._dirty = True

    def evaluate(
        self, t: int, values: np.ndarray, asserted: np.ndarray, retracted: np.ndarray
    ) -> list[RuleHit]:
        """Violations at step ``t`` given the beliefs ``values`` and what changed at this step."""
        if t == 0:
            true = np.flatnonzero(values)
            for op in ("now", "prev", "ever", "recent"):
                self._set(op, true, True)
        else:
            self._set("now", asserted, True)
            self._set("now", retracted, False)
            self._set("prev", self._last_up, True)  # prev at t = beliefs at t - 1
            self._set("prev", self._last_down, False)
            self._set("ever", asserted, True)
            self._set("recent", asserted, True)
            self._fell_at[retracted] = t
            if retracted.size:
                self._expiry[t + self.recent_steps].extend(retracted.tolist())
            due = np.array(self._expiry.pop(t, []), dtype=np.int64)
            if due.size:  # still false since it fell W steps ago: no longer recent
                due = due[(self._fell_at[due] == t - self.recent_steps) & ~values[due]]
                self._set("recent", due, False)
        self._last_up, self._last_down = asserted, retracted
        if self._dirty:
            self._hits = self._solve()
            self._dirty = False
        return self._hits

    def facts(self) -> list[str]:
        """The beliefs and past-time operators true now, as DIARC terms (what a Prolog run is given)."""
        out = [str(self._now[i]) for i in np.flatnonzero(self._state["now"]).tolist()]
        for op in TEMPORAL:
            out += [str(self._ops[op][i]) for i in np.flatnonzero(self._state[op]).tolist()]
        return out

    def _text(self, sym: clingo.Symbol) -> str:
        text = self._atom_text.get(sym)
        if text is None:
            args = ",".join(a.string if a.type == clingo.SymbolType.String else str(a) for a in sym.arguments)
            text = self._atom_text[sym] = f"{canonical_name(sym.name)}({args})"
        return text

    def _beliefs_in(self, key: clingo.Symbol) -> list[str]:
        parts = key.arguments if key.type == clingo.SymbolType.Function and key.name == "" else [key]
        return [
            self._text(p)
            for p in parts
            if p.type == clingo.SymbolType.Function and p.name in self._beliefs and p.arguments
        ]

    def _parse(self, sym: clingo.Symbol) -> tuple[str, str, list[str]]:
        """(rule, key, beliefs) of a shown ``violation/2`` or ``involves/3`` symbol, cached per symbol."""
        parsed = self._parsed.get(sym)
        if parsed is None:
            args = sym.arguments
            key = args[1]
            beliefs = self._beliefs_in(key) if sym.name == "violation" else [self._text(args[2])]
            parsed = self._parsed[sym] = (args[0].name, str(key), beliefs)
        return parsed

    def _solve(self) -> list[RuleHit]:
        shown: list[clingo.Symbol] = []

        def on_model(m: clingo.Model) -> None:
            shown.extend(m.symbols(shown=True))

        if self.users:
            result = solve_within(self._ctl, on_model, self.budget.solve_seconds, self.users)
        else:  # the shipped rules: tested, under 1 ms
            result = self._ctl.solve(on_model=on_model)
        if not result.satisfiable:
            raise VlaprobeError("the rules have no answer for this step; make every rule derive violation/2")
        found: dict[tuple[str, str], list[str]] = {}
        extra: dict[tuple[str, str], list[str]] = defaultdict(list)
        for sym in shown:
            rule, key, beliefs = self._parse(sym)
            if sym.name == "violation":
                found[rule, key] = beliefs
            else:
                extra[rule, key] += beliefs
        return [
            RuleHit(rule, key, tuple(dict.fromkeys(atoms + sorted(extra.get((rule, key), [])))))
            for (rule, key), atoms in sorted(found.items())
        ]


def _literal(lookup: clingo.SymbolicAtoms, symbol: clingo.Symbol) -> int:
    """The solver literal of a grounded atom (every atom looked up here was added as an external)."""
    atom = lookup[symbol]
    if atom is None:
        raise VlaprobeError(f"the rules' atom {symbol} was not grounded; report this as a bug")
    return atom.literal
