"""A LIBERO task's BDDL problem file as typed data: regions, fixtures, objects, ``:init`` and ``:goal``.

The s-expression is tokenised by the ``bddl`` package's ``scan_tokens`` (installed with LIBERO; it lower-cases
the text, which only changes the ``:language`` line and the predicates' spelling); the sections are read here.
No simulator and no assets are needed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols.goals import Conjunct, GoalConjunction, goal_predicate

Sexp = str | list["Sexp"]


@dataclass(frozen=True)
class Named:
    """An object or fixture instance and its LIBERO category (``akita_black_bowl_1 - akita_black_bowl``)."""

    name: str
    category: str


@dataclass(frozen=True)
class Region:
    """A BDDL region: ``name`` as the simulator names its site (``<target>_<local>``), on ``target``."""

    name: str
    target: str
    local: str


@dataclass(frozen=True)
class Fact:
    """One ``:init`` fact, e.g. ``("on", ("plate_1", "main_table_plate_region"))`` (predicate lower-case)."""

    predicate: str
    args: tuple[str, ...]


@dataclass(frozen=True)
class BddlProblem:
    """The sections of one BDDL problem that the scene, vocabulary and goal are read from, in file order."""

    problem_class: str
    """The ``(problem ...)`` name, lower-case (``libero_tabletop_manipulation``)."""
    regions: tuple[Region, ...]
    fixtures: tuple[Named, ...]
    objects: tuple[Named, ...]
    obj_of_interest: tuple[str, ...]
    init: tuple[Fact, ...]
    goal: GoalConjunction


def _typed_names(tokens: list[Sexp]) -> tuple[Named, ...]:
    """``a b - kind c - other`` -> Named(a, kind), Named(b, kind), Named(c, other)."""
    out: list[Named] = []
    pending: list[str] = []
    words = [t for t in tokens if isinstance(t, str)]
    i = 0
    while i < len(words):
        if words[i] == "-" and i + 1 < len(words):
            out += [Named(n, words[i + 1]) for n in pending]
            pending, i = [], i + 2
        else:
            pending.append(words[i])
            i += 1
    if pending:
        raise ValueError(f"names without a category: {pending}")
    return tuple(out)


def _region(entry: Sexp) -> Region:
    if not isinstance(entry, list) or not entry or not isinstance(entry[0], str):
        raise ValueError(f"malformed region {entry!r}")
    local = entry[0]
    targets = [e[1] for e in entry[1:] if isinstance(e, list) and e[:1] == [":target"] and len(e) > 1]
    if not targets or not isinstance(targets[0], str):
        raise ValueError(f"region {local} has no :target")
    return Region(name=f"{targets[0]}_{local}", target=targets[0], local=local)


def _atom(entry: Sexp) -> tuple[str, tuple[str, ...]]:
    if not isinstance(entry, list) or not all(isinstance(e, str) for e in entry) or not entry:
        raise ValueError(f"malformed fact {entry!r}")
    words = [str(e) for e in entry]
    return words[0], tuple(words[1:])


def _goal(section: list[Sexp]) -> GoalConjunction:
    body: list[Sexp] = section
    if len(section) == 1 and isinstance(section[0], list) and section[0][:1] == ["and"]:
        body = section[0][1:]
    conjuncts = []
    for entry in body:
        pred, args = _atom(entry)
        conjuncts.append(Conjunct(goal_predicate(pred), args))
    return GoalConjunction(tuple(conjuncts))


def parse_problem(tokens: Sexp) -> BddlProblem:
    """The typed problem of a tokenised BDDL file (``(define (problem X) (:domain ...) (:regions ...) ...)``)."""
    if not isinstance(tokens, list) or tokens[:1] != ["define"]:
        raise ValueError("not a BDDL problem (no `define`)")
    sections: dict[str, list[Sexp]] = {}
    problem_class = ""
    for group in tokens[1:]:
        if isinstance(group, list) and group and isinstance(group[0], str):
            if group[0] == "problem" and len(group) > 1 and isinstance(group[1], str):
                problem_class = group[1]
            sections[group[0]] = group[1:]
    return BddlProblem(
        problem_class=problem_class,
        regions=tuple(_region(r) for r in sections.get(":regions", [])),
        fixtures=_typed_names(sections.get(":fixtures", [])),
        objects=_typed_names(sections.get(":objects", [])),
        obj_of_interest=tuple(str(t) for t in sections.get(":obj_of_interest", []) if isinstance(t, str)),
        init=tuple(Fact(*_atom(f)) for f in sections.get(":init", [])),
        goal=_goal(sections.get(":goal", [])),
    )


def parse_bddl(text: str) -> BddlProblem:
    """Parse the text of a BDDL problem (ValueError or the tokeniser's Exception when malformed)."""
    from bddl.parsing import scan_tokens

    return parse_problem(scan_tokens(string=text))


def read_problem(path: Path) -> BddlProblem:
    """Read and parse one BDDL file; a malformed file is a one-line error naming it."""
    try:
        return parse_bddl(path.read_text())
    except FileNotFoundError:
        raise VlaprobeError(f"BDDL file not found: {path}; reinstall LIBERO (`make setup`)") from None
    except Exception as exc:  # the bddl tokeniser raises bare Exceptions on unbalanced parentheses
        raise VlaprobeError(f"cannot read BDDL file {path}: {exc}; reinstall LIBERO (`make setup`)") from None
