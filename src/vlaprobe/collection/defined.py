"""Which atoms are defined in an episode: the per-episode ``atoms_defined`` attribute (one writer, one reader).

A union store (a suite whose tasks have different objects) has the union of the tasks' vocabularies; an atom
naming an object absent from an episode's scene is undefined there. The attribute lists, per label head, the
atoms that are *not* defined (version 1). Episodes without it read as "all defined".
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

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


def episode_defined(
    attrs: Mapping[str, Json], atom_names: Mapping[str, Sequence[str]]
) -> dict[str, np.ndarray]:
    """Head -> bool (atoms,): one episode's :func:`read_defined` for every head (all True without the attribute)."""
    return {head: read_defined(attrs, atom_names, head) for head in atom_names}


def only_defined(
    values: Mapping[str, np.ndarray], defined: Mapping[str, np.ndarray] | None
) -> dict[str, np.ndarray]:
    """Head -> ``values`` (atoms,) or (T, atoms) with the episode's undefined atoms False: an undefined atom is
    neither true nor false, so it is never asserted (read as stored labels or as probe predictions alike).
    The arrays themselves where every atom is defined (``defined`` None: a live episode)."""
    out = {}
    for head, v in values.items():
        mask = None if defined is None else defined.get(head)
        out[head] = v if mask is None or mask.all() else np.asarray(v, bool) & mask
    return out


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


@dataclass(frozen=True)
class TaskColumns:
    """Where one task's label columns sit among a store's (the union vocabulary), and what the task leaves
    undefined there: the store's atoms absent from the task's vocabulary, and the task's own atoms it cannot
    label (``Labeler.undefined_action_atoms``: ``should-move-towards`` without a pick-and-place goal)."""

    columns: dict[str, np.ndarray]
    """Head -> int (task atoms,): the store column of each of the task's atoms."""
    width: dict[str, int]
    """Head -> the store's number of atoms."""
    undefined: dict[str, list[str]]
    """Head -> the store's atoms undefined in this task (store order)."""

    @classmethod
    def of(
        cls,
        store_atoms: Mapping[str, Sequence[str]],
        task_atoms: Mapping[str, Sequence[str]],
        task_undefined: Mapping[str, Sequence[str]] | None = None,
        advice: str = "collect this task into another store (--tasks, --out)",
    ) -> TaskColumns:
        """The columns of ``task_atoms`` in ``store_atoms`` (every task atom must be a store atom; else one line
        ending in ``advice``)."""
        columns, undefined = {}, {}
        for head, names in store_atoms.items():
            at = {a: i for i, a in enumerate(names)}
            own = list(task_atoms[head])
            missing = [a for a in own if a not in at]
            if missing:
                raise VlaprobeError(
                    f"the task's {head} atoms {missing[:3]} are not in the store's vocabulary (the union of the "
                    f"selected tasks' scenes); {advice}"
                )
            columns[head] = np.array([at[a] for a in own], np.int64)
            gone = set(names) - set(own) | set((task_undefined or {}).get(head, ()))
            undefined[head] = [a for a in names if a in gone]
        return cls(columns, {h: len(v) for h, v in store_atoms.items()}, undefined)

    def widen(self, head: str, bits: np.ndarray) -> np.ndarray:
        """bool (T, store atoms) of the task's (T, task atoms) labels; False in the columns the task lacks.
        The task's own array, unchanged, where its columns are the store's."""
        cols, width = self.columns[head], self.width[head]
        if len(cols) == width and np.array_equal(cols, np.arange(width)):
            return bits
        out = np.zeros((len(bits), width), dtype=bool)
        out[:, cols] = bits
        return out

    def attrs(self, atom_names: Mapping[str, Sequence[str]]) -> JsonObject:
        """The episode's ``atoms_defined`` attribute (:func:`defined_attrs`); none when every atom is defined
        (single-vocabulary stores, LIBERO-spatial's among them, keep their attributes)."""
        if not any(self.undefined.values()):
            return {}
        return defined_attrs(atom_names, {h: v for h, v in self.undefined.items() if v})


def undefined_counts(
    attrs: Sequence[Mapping[str, Json]], atom_names: Mapping[str, Sequence[str]]
) -> dict[str, tuple[int, int]]:
    """Head -> (atoms undefined in some episode, episodes leaving some atom undefined), from the episodes'
    attributes (``vlaprobe info``)."""
    out = {}
    for head, names in atom_names.items():
        rows = [~read_defined(a, atom_names, head) for a in attrs]
        undefined = np.stack(rows) if rows else np.zeros((0, len(names)), bool)
        out[head] = (int(undefined.any(0).sum()), int(undefined.any(1).sum()))
    return out
