"""Which atoms are defined in an episode: the per-episode ``atoms_defined`` attribute (one writer, one reader).

A union store (a suite whose tasks have different objects) has the union of the tasks' vocabularies; an atom
naming an object absent from an episode's scene is undefined there. The attribute lists, per label head, the
atoms that are *not* defined (version 1). Episodes without it read as "all defined".
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import Json, JsonObject

ATTR = "atoms_defined"
VERSION = 1


def defined_attrs(
    atom_names: Mapping[str, Sequence[str]], undefined: Mapping[str, Sequence[str]]
) -> JsonObject:
    """Episode attributes recording ``undefined`` atoms per head (each must be in that head's ``atom_names``)."""
    out: dict[str, Json] = {}
    for head, names in undefined.items():
        unknown = sorted(set(names) - set(atom_names.get(head, ())))
        if unknown:
            raise ValueError(
                f"head {head!r}: undefined atoms {unknown[:3]} are not in the store's vocabulary"
            )
        out[head] = sorted(names)
    return {ATTR: {"version": VERSION, "undefined": out}}


def read_defined(attrs: Mapping[str, Json], atom_names: Mapping[str, Sequence[str]], head: str) -> np.ndarray:
    """bool (atoms,) for ``head`` in ``atom_names[head]`` order: False where the episode says undefined."""
    mask = np.ones(len(atom_names[head]), dtype=bool)
    record = attrs.get(ATTR)
    if record is None:
        return mask
    if not isinstance(record, Mapping) or record.get("version") != VERSION:
        version = record.get("version") if isinstance(record, Mapping) else record
        raise VlaprobeError(
            f"episode attribute {ATTR} has version {version!r}, this vlaprobe reads {VERSION}; "
            "use the vlaprobe that wrote the store"
        )
    undefined = record.get("undefined") or {}
    assert isinstance(undefined, Mapping)
    names = set(undefined.get(head) or [])
    mask[[i for i, n in enumerate(atom_names[head]) if n in names]] = False
    return mask


def defined_rows(
    attrs: Sequence[Mapping[str, Json]],
    lengths: Sequence[int],
    atom_names: Mapping[str, Sequence[str]],
    head: str,
) -> np.ndarray:
    """bool (sum(lengths), atoms): each episode's :func:`read_defined` repeated over its steps."""
    width = len(atom_names[head])
    rows = [
        np.broadcast_to(read_defined(a, atom_names, head), (n, width))
        for a, n in zip(attrs, lengths, strict=True)
    ]
    return np.concatenate(rows) if rows else np.ones((0, width), dtype=bool)
