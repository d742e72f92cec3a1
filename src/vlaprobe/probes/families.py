"""Atom families: the groups of atoms the issue of an observer that must look asks about, across predicates.

- ``grasped`` and ``should-move-towards``: the action head's predicates;
- ``on(bowl, plate)``: a bowl on a plate, LIBERO-spatial's goal atom (``on(akita_black_bowl_1,plate_1)``);
- ``relations``: the spatial relations ``behind``, ``in-front-of``, ``left-of``, ``right-of``;
- ``other object state``: every other object atom (``on`` otherwise, ``on-table``, ``inside``, ``open``,
  ``turned-on``).

Every atom belongs to exactly one family; a head lists the families its probed atoms fall in, in this order.
"""

from __future__ import annotations

import numpy as np

from vlaprobe.symbols.vocabulary import parse_atom

FAMILIES = ("grasped", "should-move-towards", "on(bowl, plate)", "relations", "other object state")
RELATIONS = ("behind", "in-front-of", "left-of", "right-of")


def family_of(atom: str) -> str:
    """The family of one atom (one of :data:`FAMILIES`)."""
    pred, args = parse_atom(atom)
    if pred in FAMILIES:
        return pred
    if pred == "on" and "bowl" in args[0] and "plate" in args[-1]:
        return "on(bowl, plate)"
    return "relations" if pred in RELATIONS else "other object state"


def family_columns(atoms: list[str]) -> dict[str, np.ndarray]:
    """Family -> the positions of its atoms in ``atoms``, for the families present, in :data:`FAMILIES` order."""
    of = [family_of(a) for a in atoms]
    return {f: np.flatnonzero([x == f for x in of]) for f in FAMILIES if f in of}
