"""Does the instruction still name the object to pick, and only it? The check of ``--inits sampled-swap``.

LIBERO-spatial's instructions name the bowl to pick by where it is ("the black bowl between the plate and the
ramekin", "next to the cookie box", "on the stove", "in the top drawer of the wooden cabinet", "from table
center"), and the other black bowl is the distractor. A layout that swaps which region each object starts in
can make that description fit the other bowl as well, or not fit the bowl to pick: the expert and the
detectors would still use the goal's bowl, but the instruction would no longer say which one. Here the
instruction's referring phrase is parsed into a relation and its anchors (names matched word by word against
the scene's objects and regions), then checked on a settled world state against every object of the pick's
kind (the same name up to its number); a layout where it does not single out the pick is rejected (re-drawn).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from vlaprobe.symbols import Goal, Scene, WorldState
from vlaprobe.symbols.vocabulary import atom

NEXT_TO = 0.15
"""Metres (horizontal, between origins) within which an object is "next to" another; LIBERO-spatial's
next-to regions are ~12 cm from their anchor."""
MARGIN = 0.05
"""Metres by which every other object of the pick's kind must be farther from the anchor (or the centre)."""
BETWEEN_WIDTH = 0.06
"""Metres from the line between the two anchors within which an object is "between" them."""
BETWEEN_SPAN = (0.15, 0.85)
"""Range of the position along the anchors' segment (0: first anchor, 1: second) that counts as between."""
CENTER = 0.08
"""Metres from the table centre within which an object is "at the table center"."""

_PATTERNS = (
    ("between", re.compile(r"^between the (.+?) and the (.+)$")),
    ("next_to", re.compile(r"^next to the (.+)$")),
    ("in", re.compile(r"^in the (.+)$")),
    ("on", re.compile(r"^on (?:top of )?the (.+)$")),
    ("center", re.compile(r"^(?:from|at|in) (?:the )?(?:table center|center of the table)$")),
)


@dataclass(frozen=True)
class Reference:
    """The instruction's description of the object to pick."""

    relation: str
    """"between", "next_to", "in", "on" or "center"."""
    anchors: tuple[str, ...]
    """The scene objects or regions it is described by (none for "center")."""


def kind(name: str) -> str:
    """An object's kind: its name without the trailing number (``akita_black_bowl_2`` -> ``akita_black_bowl``)."""
    return re.sub(r"_\d+$", "", name)


def _match(phrase: str, names: Sequence[str]) -> str | None:
    """The name most of whose words the phrase's words begin (``cookie box`` -> ``cookies_1``); None on a tie."""
    words = [w for w in re.findall(r"[a-z]+", phrase) if w not in ("the", "of", "a")]

    def score(name: str) -> int:
        tokens = [t for t in name.split("_") if not t.isdigit()]
        return sum(any(t.startswith(w) or w.startswith(t) for t in tokens) for w in words)

    scored = sorted(((score(n), n) for n in names), reverse=True)
    if not scored or scored[0][0] == 0 or (len(scored) > 1 and scored[1][0] == scored[0][0]):
        return None
    return scored[0][1]


def _phrase(instruction: str, pick: str) -> tuple[str, re.Match[str]] | None:
    """(relation, its match) of the phrase after the pick's noun (``... black bowl <phrase> and place it``)."""
    noun = kind(pick).split("_")[-1]
    text = instruction.lower().strip().rstrip(".")
    found = re.search(rf"\b{noun}\b (.+?) and (?:place|put)\b", text)
    if found is None:
        return None
    for relation, pattern in _PATTERNS:
        m = pattern.match(found.group(1).strip())
        if m is not None:
            return relation, m
    return None


def instruction_form(instruction: str, pick: str) -> str | None:
    """The relation the instruction describes the pick by, or None when it has no known form (no simulator:
    the up-front check of ``--inits sampled-swap``)."""
    found = _phrase(instruction, pick)
    return None if found is None else found[0]


def parse_reference(instruction: str, goal: Goal, scene: Scene) -> Reference | None:
    """The relation and anchors (the scene's names) of the instruction's description of the pick; None when
    the instruction has no known form or an anchor matches no single name."""
    found = _phrase(instruction, goal.pick)
    if found is None:
        return None
    relation, m = found
    pool = scene.containers if relation == "in" else scene.tabletop
    anchors = tuple(_match(g, pool) for g in m.groups())
    if any(a is None for a in anchors):
        return None
    return Reference(relation, tuple(a for a in anchors if a is not None))


def reference_problems(
    ref: Reference,
    goal: Goal,
    scene: Scene,
    state: WorldState,
    object_bits: np.ndarray,
    object_atoms: Sequence[str],
    center: np.ndarray | None = None,
) -> list[str]:
    """Why the described object is not exactly the pick in this state (empty: the instruction names it alone).

    ``object_bits`` / ``object_atoms``: the labeler's object atoms of ``state`` (for "on" and "in");
    ``center``: (x, y) of the table centre (for "center")."""
    xy = {n: state.pos[i, :2] for i, n in enumerate(scene.tabletop)}
    if ref.relation in ("on", "in"):
        pred = "on" if ref.relation == "on" else "inside"
        bits: Mapping[str, bool] = dict(zip(object_atoms, map(bool, object_bits), strict=True))
        fits = {c: bits.get(atom(pred, c, ref.anchors[0]), False) for c in candidates(goal, scene)}
        return _problems(ref, goal, fits)
    return placement_problems(ref, goal, scene, xy, center)


def candidates(goal: Goal, scene: Scene) -> list[str]:
    """The objects of the pick's kind (the pick and its distractors)."""
    return [n for n in scene.pickupable if kind(n) == kind(goal.pick)]


def placement_problems(
    ref: Reference, goal: Goal, scene: Scene, xy: Mapping[str, np.ndarray], center: np.ndarray | None
) -> list[str]:
    """The check of a spatial description ("between", "next to", "center") on objects' (x, y) positions; an
    object missing from ``xy`` is not judged (its place is unknown, e.g. before a reset). "on" and "in" need the
    detectors: no problem here."""
    if ref.relation in ("on", "in") or any(a not in xy for a in ref.anchors):
        return []
    known = [c for c in candidates(goal, scene) if c in xy]
    fits: dict[str, bool] = {}
    if ref.relation == "between":
        a, b = xy[ref.anchors[0]], xy[ref.anchors[1]]
        axis = b - a
        for c in known:
            t = float(np.dot(xy[c] - a, axis) / max(np.dot(axis, axis), 1e-12))
            off = float(np.linalg.norm(a + t * axis - xy[c]))
            fits[c] = BETWEEN_SPAN[0] <= t <= BETWEEN_SPAN[1] and off <= BETWEEN_WIDTH
    else:
        if ref.relation == "center" and center is None:
            return ["the instruction names the table centre, which the task's regions do not give"]
        target = xy[ref.anchors[0]] if ref.relation == "next_to" else np.asarray(center)[:2]
        limit = NEXT_TO if ref.relation == "next_to" else CENTER
        dist = {c: float(np.linalg.norm(xy[c] - target)) for c in known}
        near = dist.get(goal.pick, np.inf)
        # The pick within reach of the anchor; another object of its kind not clearly farther also fits.
        fits = {c: d <= limit and (c == goal.pick or d < near + MARGIN) for c, d in dist.items()}
    return _problems(ref, goal, fits) if goal.pick in xy else []


def _problems(ref: Reference, goal: Goal, fits: Mapping[str, bool]) -> list[str]:
    what = f"{ref.relation.replace('_', ' ')} {' and '.join(ref.anchors)}".strip()
    problems = []
    if not fits.get(goal.pick, False):
        problems.append(f"the instruction ({what}) no longer fits {goal.pick}")
    problems.extend(
        f"the instruction ({what}) also fits {c}" for c, ok in fits.items() if c != goal.pick and ok
    )
    return problems
