"""Probes + hidden states -> a full assignment of every atom, the same for `vlaprobe cognition` and the live server.

The probes only cover the atoms that were not near-constant in training (the kept atoms); the others are
held at their training-majority value (train frequency >= 0.5, from the probes' metadata) and marked not
probed, with probability NaN. Each head is read at one layer (default: the probes' ``default_layer``, the
earliest layer statistically tied with the head's best). Every step goes through
:meth:`vlaprobe.probes.probeset.ProbeSet.logits` (the one application of a probe,
:func:`vlaprobe.probes.apply.apply_probes`) and ``torch.sigmoid``, as ``ProbeSet.probabilities`` does; a stored
episode is read row by row with the very same operations as a live step, so the live server, ``vlaprobe
monitor`` and the probe set give identical predictions, bit for bit.

    readout = ProbeReadout.load("runs/default/probes")
    a = readout.assign(hidden)          # (hidden states, hidden) of one step -> Assignment
    a.values["object"], a.probs["object"], a.probed["object"]
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols import HEADS

if TYPE_CHECKING:
    from vlaprobe.probes.probeset import ProbeSet


@dataclass(frozen=True)
class Assignment:
    """Truth values of every atom of each head, in vocabulary order (one step, or T steps on a leading axis)."""

    atoms: Mapping[str, tuple[str, ...]]
    """Per head, every atom in vocabulary order."""
    values: Mapping[str, np.ndarray]
    """Per head, bool: the probe's prediction, or the training-majority value where not probed."""
    probs: Mapping[str, np.ndarray]
    """Per head, float32 probability of being true; NaN where not probed."""
    probed: Mapping[str, np.ndarray]
    """Per head, bool: whether a probe predicts the atom."""


@dataclass(frozen=True)
class _Head:
    name: str
    atoms: tuple[str, ...]
    layer: int
    kept: np.ndarray  # positions of the probe's outputs among ``atoms``
    majority: np.ndarray  # (atoms,) bool
    probed: np.ndarray  # (atoms,) bool


def _blank(name: str, atoms: Sequence[str]) -> _Head:
    """A head without probes: every atom unknown (not probed, false)."""
    n = len(atoms)
    return _Head(name, tuple(atoms), -1, np.zeros(0, np.int64), np.zeros(n, bool), np.zeros(n, bool))


class ProbeReadout:
    """The probes of each head at one layer, as numpy arrays, turning hidden states into an Assignment."""

    def __init__(
        self,
        probes: ProbeSet,
        layers: Mapping[str, int] | None = None,
        unknown: Mapping[str, Sequence[str]] | None = None,
    ) -> None:
        """``unknown``: heads the probes may lack, with their atoms: read as unknown (not probed, false), and
        listed in :attr:`unknown` when the probes lack them (``vlaprobe cognition`` on an object-only folder)."""
        layers, unknown = dict(layers or {}), dict(unknown or {})
        missing = [h for h in HEADS if h not in probes.heads and h not in unknown]
        if missing:
            raise VlaprobeError(
                f"the probes in {probes.where} have no {missing[0]!r} head; the cognition "
                "needs it: train with --heads object action"
            )
        self.probes = probes
        """The probe set read."""
        self.threshold = probes.threshold
        self.pooling = probes.pooling
        self.model_id = probes.model_id
        self.num_hidden_states = probes.num_hidden_states
        self.hidden_size = probes.hidden_size
        self.unknown: tuple[str, ...] = tuple(h for h in HEADS if h not in probes.heads)
        """Heads without probes, whose atoms are all unknown (not probed, false)."""
        self._heads = {
            h: _blank(h, unknown[h]) if h in self.unknown else self._pull(probes, h, layers.get(h))
            for h in HEADS
        }
        self.layers: dict[str, int] = {h: self._heads[h].layer for h in HEADS if h not in self.unknown}
        """Hidden-state index each probed head reads."""
        self.atoms: dict[str, tuple[str, ...]] = {h: self._heads[h].atoms for h in HEADS}
        self.probed: dict[str, np.ndarray] = {h: self._heads[h].probed for h in HEADS}

    @classmethod
    def load(
        cls, folder: str | Path, layers: Mapping[str, int] | None = None, model_id: str | None = None
    ) -> ProbeReadout:
        """Read a probe folder (see :class:`vlaprobe.probes.probeset.ProbeSet`) and pull out its weights."""
        from vlaprobe.probes.probeset import ProbeSet

        return cls(ProbeSet.load(folder, model_id=model_id), layers)

    @staticmethod
    def _pull(probes: ProbeSet, head: str, layer: int | None) -> _Head:
        atoms = tuple(probes.atom_names(head))
        layer = probes.default_layer(head) if layer is None else int(layer)
        if layer not in probes.layers:
            raise VlaprobeError(
                f"no {head} probe for hidden state {layer}; these probes cover {probes.layers}"
            )
        if probes.tensors.get(f"{head}.weight") is None or probes.tensors.get(f"{head}.bias") is None:
            raise VlaprobeError(f"the {head} probes have no weights or biases; run vlaprobe train again")
        position = {a: j for j, a in enumerate(atoms)}
        kept = np.array([position[a] for a in probes.atoms(head)], dtype=np.int64)
        majority = np.zeros(len(atoms), dtype=bool)
        for atom, frequency in probes.dropped(head).items():
            if atom in position:
                majority[position[atom]] = frequency >= 0.5
        probed = np.zeros(len(atoms), dtype=bool)
        probed[kept] = True
        return _Head(head, atoms, layer, kept, majority, probed)

    def _probs(self, head: _Head, x: np.ndarray) -> np.ndarray:
        """Probabilities of the kept atoms from one hidden state (hidden,) or (7, hidden) at the head's layer:
        ``ProbeSet.probabilities``' operations exactly."""
        if head.name in self.unknown:
            return np.zeros(0, dtype=np.float32)
        import torch  # here, not at the top: the cognition imports without torch (the probe set needs it)

        row = torch.from_numpy(np.array(x, dtype=np.float32))  # a copy: stored rows may be read-only
        z = self.probes.logits(row, head.name, head.layer)
        return torch.sigmoid(z).numpy()

    def _fill(self, head: _Head, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        values = head.majority.copy()
        values[head.kept] = p > self.threshold
        probs = np.full(len(head.atoms), np.nan, dtype=np.float32)
        probs[head.kept] = p
        return values, probs

    def assign(self, hidden: np.ndarray) -> Assignment:
        """One step: ``hidden`` holds every hidden state of the step, (L, hidden) or (L, 7, hidden)."""
        x = np.asarray(hidden)
        expected = 3 if self.pooling == "action_tokens" else 2
        if x.ndim != expected or x.shape[0] != self.num_hidden_states or x.shape[-1] != self.hidden_size:
            raise VlaprobeError(
                f"hidden states of shape {x.shape} do not fit these probes ({self.num_hidden_states} hidden "
                f"states of size {self.hidden_size}, pooling {self.pooling}); pass every hidden state of one step"
            )
        values, probs = {}, {}
        for name, head in self._heads.items():
            values[name], probs[name] = self._fill(head, self._probs(head, x[head.layer]))
        return Assignment(self.atoms, values, probs, self.probed)

    def assign_steps(self, rows: Mapping[str, np.ndarray]) -> Assignment:
        """T steps at once from each head's layer, ``rows[head]`` (T, hidden) (as ``ActivationStore.layer``
        reads them; none for a head in :attr:`unknown`); arrays of the result get a leading T axis. Row for row
        the same operations as :meth:`assign`."""
        values, probs = {}, {}
        steps = len(next(iter(rows.values())))
        for name, head in self._heads.items():
            x = np.asarray(rows[name]) if name not in self.unknown else np.zeros((steps, self.hidden_size))
            if x.shape[-1] != self.hidden_size:
                raise VlaprobeError(
                    f"rows of {name} have hidden size {x.shape[-1]}, the probes {self.hidden_size}"
                )
            out = [self._fill(head, self._probs(head, r)) for r in x]
            n = len(head.atoms)
            values[name] = np.array([v for v, _ in out], dtype=bool).reshape(len(x), n)
            probs[name] = np.array([p for _, p in out], dtype=np.float32).reshape(len(x), n)
        return Assignment(self.atoms, values, probs, self.probed)
