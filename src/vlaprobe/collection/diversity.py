"""How diverse a store's ground truth is: distinct object states, atoms that change within episodes, base rates.

A probe can only show that a model encodes an atom if the atom varies independently of what is trivially known
(the task, the elapsed time). These figures say how much the data allow that: ``vlaprobe info`` prints them
and the report shows them next to the probes.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class HeadDiversity:
    """One label head's diversity over a set of episodes."""

    atoms: tuple[str, ...]
    """Atom names, in column order."""
    base_rate: tuple[float, ...]
    """Share of all rows in which each atom is true."""
    episodes_varying: tuple[int, ...]
    """Per atom, in how many episodes it changes value at least once."""
    distinct_states: int
    """Distinct rows (state vectors of this head) over all episodes."""
    distinct_first_states: int
    """Distinct state vectors at the first row of the episodes."""

    @property
    def varying(self) -> int:
        """Atoms that change within at least one episode."""
        return sum(n > 0 for n in self.episodes_varying)

    @property
    def ever_true(self) -> int:
        return sum(r > 0 for r in self.base_rate)

    @property
    def always_true(self) -> int:
        return sum(r == 1 for r in self.base_rate)


@dataclass(frozen=True)
class Diversity:
    """Per head (``object``, ``action``) :class:`HeadDiversity`, and the rows and episodes counted."""

    episodes: int
    rows: int
    heads: dict[str, HeadDiversity]
    perturbed_episodes: int = 0
    """Episodes with at least one perturbation mark (0 for stores collected without ``--perturb``)."""
    applied: dict[str, int] = field(default_factory=dict)
    """Perturbations that happened, per kind."""
    missed: dict[str, int] = field(default_factory=dict)
    """Perturbations drawn that did not happen, per "kind: reason class" ("knock_off: too late"); empty for
    stores collected before they were recorded."""

    def as_dict(self) -> dict[str, object]:
        """JSON-ready summary (counts; per-atom lists in atom order)."""
        return {
            "episodes": self.episodes,
            "rows": self.rows,
            "perturbed_episodes": self.perturbed_episodes,
            "perturbations_applied": dict(self.applied),
            "perturbations_missed": dict(self.missed),
            "heads": {
                head: {
                    "atoms": len(h.atoms),
                    "distinct_states": h.distinct_states,
                    "distinct_first_states": h.distinct_first_states,
                    "varying_atoms": h.varying,
                    "ever_true": h.ever_true,
                    "always_true": h.always_true,
                    "base_rate": dict(zip(h.atoms, (round(r, 5) for r in h.base_rate), strict=True)),
                    "episodes_varying": dict(zip(h.atoms, h.episodes_varying, strict=True)),
                }
                for head, h in self.heads.items()
            },
        }


def head_diversity(atoms: Sequence[str], episodes: Sequence[np.ndarray]) -> HeadDiversity:
    """:class:`HeadDiversity` of one head from its per-episode (rows, atoms) bool arrays."""
    n = len(atoms)
    if not episodes:
        return HeadDiversity(tuple(atoms), (0.0,) * n, (0,) * n, 0, 0)
    rows = np.concatenate([np.asarray(e, dtype=bool).reshape(-1, n) for e in episodes])
    varying = np.zeros(n, dtype=np.int64)
    for e in episodes:
        e = np.asarray(e, dtype=bool).reshape(-1, n)
        varying += (e != e[:1]).any(axis=0) if len(e) else 0
    first = np.stack([np.asarray(e, dtype=bool).reshape(-1, n)[0] for e in episodes if len(e)])
    return HeadDiversity(
        atoms=tuple(atoms),
        base_rate=tuple(float(r) for r in rows.mean(axis=0)) if len(rows) else (0.0,) * n,
        episodes_varying=tuple(int(v) for v in varying),
        distinct_states=len(np.unique(np.packbits(rows, axis=1), axis=0)) if len(rows) else 0,
        distinct_first_states=len(np.unique(np.packbits(first, axis=1), axis=0)),
    )


def diversity(
    atom_names: Mapping[str, Sequence[str]],
    episodes: Sequence[Mapping[str, np.ndarray]],
    perturbed_episodes: int = 0,
    applied: Mapping[str, int] | None = None,
    missed: Mapping[str, int] | None = None,
) -> Diversity:
    """:class:`Diversity` from episodes given as head -> (rows, atoms) bool arrays."""
    heads = {head: head_diversity(names, [e[head] for e in episodes]) for head, names in atom_names.items()}
    rows = sum(len(e[next(iter(atom_names))]) for e in episodes)
    return Diversity(len(episodes), rows, heads, perturbed_episodes, dict(applied or {}), dict(missed or {}))


def store_diversity(path: object, success_only: bool = False) -> Diversity:
    """:class:`Diversity` of an activation store (reads only the atom arrays and the perturbation marks)."""
    from vlaprobe.collection.store import ATOM_ARRAYS, ActivationStore

    store = ActivationStore.open(path)  # type: ignore[arg-type]
    names = store.atom_names
    episodes, perturbed = [], 0
    applied: Counter[str] = Counter()
    missed: Counter[str] = Counter()
    for info in store.episodes(success_only=success_only):
        arrays = store.episode(info.key)
        episodes.append({head: np.asarray(arrays[ATOM_ARRAYS[head]]) for head in names})
        attrs = arrays.attributes
        perturbed += bool(attrs.perturbations)
        applied.update(p.kind for p in attrs.perturbations or ())
        missed.update(f"{m.kind}: {m.reason.split(':')[0]}" for m in attrs.perturbations_missed or ())
    return diversity(names, episodes, perturbed, applied, missed)


def summary_lines(d: Diversity) -> list[str]:
    """The figures as text lines (``vlaprobe info``)."""
    lines = [f"diversity {d.episodes} episodes, {d.rows} rows, {d.perturbed_episodes} perturbed episodes"]
    if d.applied or d.missed:
        done = ", ".join(f"{k} {n}" for k, n in sorted(d.applied.items())) or "none"
        lost = ", ".join(f"{k} {n}" for k, n in sorted(d.missed.items())) or "none recorded"
        lines.append(f"  perturbations applied: {done}; drawn but not applied: {lost}")
    for head, h in d.heads.items():
        lines.append(
            f"  {head:>6}: {h.distinct_states} distinct state vectors ({h.distinct_first_states} at the first row); "
            f"{h.varying} of {len(h.atoms)} atoms change within an episode; {h.ever_true} ever true, "
            f"{h.always_true} always true"
        )
    return lines
