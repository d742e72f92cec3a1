"""The belief store: current beliefs, their per-step differences and the history of intervals.

Input arrives as one truth value per atom per step. A change counts (is *believed*) once the new value has held
``debounce`` consecutive steps, so a flicker shorter than that never reaches the beliefs, the rules or the
subgoals. Step 0 is the baseline: every true atom is asserted and nothing "changes".

The history is a list of intervals per atom, ``(first step, last step)``, last ``None`` while it still holds,
as DIARC keeps assert/retract times in its database; it answers "what held at step t", "since when has X held"
and "when did X last change" directly. Steps are the steps at which a change was believed (after the debounce).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vlaprobe.errors import VlaprobeError


@dataclass(frozen=True)
class Interval:
    """One stretch of steps during which a belief held."""

    atom: str
    first: int
    """First step it was believed."""
    last: int | None
    """Last step it was believed; None while it still holds."""


class BeliefStore:
    """Debounced beliefs over a fixed list of atoms, with their interval history."""

    def __init__(self, atoms: Sequence[str], debounce: int = 1, fixed: np.ndarray | None = None) -> None:
        if debounce < 1:
            raise VlaprobeError(
                f"debounce must be at least 1 step, got {debounce}; pass --debounce 1 or more"
            )
        self.atoms: tuple[str, ...] = tuple(atoms)
        self.index = {a: i for i, a in enumerate(self.atoms)}
        self.debounce = int(debounce)
        self.fixed = None if fixed is None else np.asarray(fixed, dtype=bool)
        """Atoms whose value never changes after step 0 (not probed); None: all may change."""
        self.reset()

    def reset(self) -> None:
        n = len(self.atoms)
        self.t = -1
        self.values: np.ndarray = np.zeros(n, dtype=bool)
        """Current beliefs, one per atom."""
        self._run: np.ndarray = np.zeros(
            n, dtype=np.int32
        )  # consecutive steps the input has disagreed with the belief
        self._start = np.full(n, -1, dtype=np.int64)  # first step of the current true interval, -1 if false
        self._changed = np.full(n, -1, dtype=np.int64)  # step of the last change, -1 if never
        self._closed: list[list[tuple[int, int]]] = [[] for _ in range(n)]

    def update(self, raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Feed one step of input; return the indices of the atoms asserted and retracted at this step."""
        raw = np.asarray(raw, dtype=bool)
        if raw.shape != self.values.shape:
            raise VlaprobeError(
                f"expected {len(self.atoms)} truth values per step, got shape {raw.shape}; pass the "
                "atoms in the order the cognition was built with"
            )
        self.t += 1
        t = self.t
        if t == 0:
            self.values = raw.copy()
            asserted = np.flatnonzero(raw)
            self._start[asserted] = 0
            return asserted, asserted[:0]
        if self.fixed is not None:
            raw = np.where(self.fixed, self.values, raw)
        differ = raw != self.values
        self._run = np.where(differ, self._run + 1, 0).astype(np.int32)
        flip = np.flatnonzero(self._run >= self.debounce)
        if flip.size == 0:
            return flip, flip
        self._run[flip] = 0
        self.values[flip] = ~self.values[flip]
        self._changed[flip] = t
        up = self.values[flip]
        asserted, retracted = flip[up], flip[~up]
        for i in retracted.tolist():
            self._closed[i].append((int(self._start[i]), t - 1))
        self._start[retracted] = -1
        self._start[asserted] = t
        return asserted, retracted

    # -- queries over the history ------------------------------------------------------------------------
    def _i(self, atom: str) -> int:
        if atom not in self.index:
            raise VlaprobeError(f"unknown atom {atom!r}; the belief store holds {len(self.atoms)} atoms")
        return self.index[atom]

    def holds(self, atom: str, t: int | None = None) -> bool:
        """Whether ``atom`` was believed at step ``t`` (default: now)."""
        i = self._i(atom)
        if t is None or t == self.t:
            return bool(self.values[i])
        if self._start[i] >= 0 and t >= self._start[i]:
            return t <= self.t
        return any(a <= t <= b for a, b in self._closed[i])

    def since(self, atom: str) -> int | None:
        """First step of the interval during which ``atom`` holds now; None if it does not hold."""
        s = int(self._start[self._i(atom)])
        return None if s < 0 else s

    def last_change(self, atom: str) -> int | None:
        """Step at which ``atom`` last changed value; None if it never changed after step 0."""
        c = int(self._changed[self._i(atom)])
        return None if c < 0 else c

    def history(self, atom: str) -> list[Interval]:
        """Every interval during which ``atom`` held, oldest first."""
        i = self._i(atom)
        out = [Interval(atom, a, b) for a, b in self._closed[i]]
        if self._start[i] >= 0:
            out.append(Interval(atom, int(self._start[i]), None))
        return out

    def at(self, t: int) -> frozenset[str]:
        """Every atom believed at step ``t``."""
        if not 0 <= t <= self.t:
            raise VlaprobeError(f"step {t} is outside the history (0..{self.t})")
        return frozenset(a for a in self.atoms if self.holds(a, t))
