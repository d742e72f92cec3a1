"""A failure probe over the sequence of one layer's hidden states (SAFE's LSTM variant, Gu et al. 2025).

The per-row probes of :mod:`vlaprobe.cognition.failure_scores` read each row alone; this one reads the rows so
far: a one-layer LSTM of :data:`UNITS` units over the standardised hidden states, a linear read-out of its state
at every row. It runs forwards only, so the score at row t depends on rows 0..t, as a live monitor's would. Every
row of a training episode is labelled with the episode's outcome (as SAFE trains it), the rows weighted as the
other probes weight them: episodes counted equally, both outcomes the same total weight. A fold's training
episodes are few, and an LSTM memorises them within tens of steps: every step sees its rows with fresh Gaussian
noise (:data:`INPUT_NOISE`), and :data:`VALIDATION` of them (stratified by outcome, drawn from the seed) are held
out, the weights of the step with the lowest validation loss kept.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch

UNITS = 32
"""Hidden units of the LSTM."""
EPOCHS = 200
"""Most full-batch Adam steps; the kept weights are those of the step with the lowest validation loss."""
VALIDATION = 0.25
"""Share of each outcome's training episodes held out to choose the step (at least one of each outcome)."""
LEARNING_RATE = 1e-2
"""Adam's step size."""
WEIGHT_DECAY = 1e-3
"""Adam's L2 penalty."""
INPUT_NOISE = 0.5
"""Standard deviation of the noise added to the standardised rows at every training step. Chosen, with the step
size, on synthetic episodes whose failure is one event many rows back (the generator of
tests/cognition/test_failure_sequence.py, other seeds than the test's): without noise the LSTM memorised the
training rows (held-out ROC-AUC at the last row 0.62, 0.58, 0.72 on three seeds; 1.0 on the training episodes),
with 0.5 and a step of 1e-2 it reached 0.89, 0.89, 0.92 (1.0: 0.54 on one seed); a step of 3e-3 reached 0.63-0.85."""


class SequenceProbe:
    """The fitted LSTM; :meth:`predict_proba` scores an episode's rows as the other probes do."""

    def __init__(self, dim: int, seed: int) -> None:
        import torch

        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            self.lstm = torch.nn.LSTM(dim, UNITS, batch_first=True)
            self.head = torch.nn.Linear(UNITS, 1)
        self.mean = np.zeros(dim, dtype=np.float32)
        self.scale = np.ones(dim, dtype=np.float32)

    def _logits(self, x: torch.Tensor) -> torch.Tensor:
        """(B, T) logits of a (B, T, dim) tensor of standardised rows."""
        out, _ = self.lstm(x)
        logits: torch.Tensor = self.head(out).squeeze(-1)
        return logits

    def fit(
        self, seqs: Sequence[np.ndarray], failed: Sequence[bool], row_weight: Sequence[np.ndarray], seed: int
    ) -> None:
        """Train on ``seqs`` ((T_i, dim) each), every row labelled ``failed[i]`` with weight ``row_weight[i]``,
        the step chosen on held-out episodes (:data:`VALIDATION`)."""
        import torch

        rows = np.concatenate(seqs)
        self.mean = rows.mean(0).astype(np.float32)
        self.scale = np.maximum(rows.std(0), 1e-6).astype(np.float32)
        held = held_out(failed, seed)
        episodes = list(zip(seqs, failed, row_weight, strict=True))
        fit_x, fit_y, fit_w = self._batch([e for i, e in enumerate(episodes) if i not in held])
        val_x, val_y, val_w = self._batch([episodes[i] for i in sorted(held)])
        params = [*self.lstm.parameters(), *self.head.parameters()]
        opt = torch.optim.Adam(params, lr=LEARNING_RATE, weight_decay=WEIGHT_DECAY)
        loss_fn = torch.nn.BCEWithLogitsLoss(reduction="none")
        best, state = float("inf"), self._state()
        noise = torch.Generator().manual_seed(seed)
        for _ in range(EPOCHS):
            opt.zero_grad()
            noisy = fit_x + INPUT_NOISE * torch.randn(fit_x.shape, generator=noise)
            loss = (loss_fn(self._logits(noisy), fit_y) * fit_w).sum()
            loss.backward()
            opt.step()
            if held:
                with torch.no_grad():
                    val = float((loss_fn(self._logits(val_x), val_y) * val_w).sum())
                if val < best:
                    best, state = val, self._state()
        if held:
            self.lstm.load_state_dict(state[0])
            self.head.load_state_dict(state[1])

    def _state(self) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
        """Copies of the weights (the best step's are restored after training)."""
        lstm = {k: v.detach().clone() for k, v in self.lstm.state_dict().items()}
        head = {k: v.detach().clone() for k, v in self.head.state_dict().items()}
        return lstm, head

    def _batch(
        self, episodes: Sequence[tuple[np.ndarray, bool, np.ndarray]]
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Padded (B, T, dim) standardised rows, (B, T) labels and (B, T) weights summing to 1 (0 on padding)."""
        import torch

        length, dim = max((len(s) for s, _, _ in episodes), default=1), len(self.mean)
        x = np.zeros((len(episodes), length, dim), dtype=np.float32)
        y = np.zeros((len(episodes), length), dtype=np.float32)
        w = np.zeros((len(episodes), length), dtype=np.float32)
        for i, (s, f, rw) in enumerate(episodes):
            x[i, : len(s)] = (s - self.mean) / self.scale
            y[i, : len(s)], w[i, : len(s)] = float(f), rw
        return torch.from_numpy(x), torch.from_numpy(y), torch.from_numpy(w / max(float(w.sum()), 1e-12))

    def predict_proba(self, h: np.ndarray) -> np.ndarray:
        """(T, 2): the probabilities of success and failure at every row of one episode's (T, dim) states."""
        import torch

        x = torch.from_numpy(((np.asarray(h, dtype=np.float32) - self.mean) / self.scale)[None])
        with torch.no_grad():
            p = torch.sigmoid(self._logits(x))[0].numpy().astype(np.float64)
        return np.stack([1 - p, p], 1)


def held_out(failed: Sequence[bool], seed: int) -> set[int]:
    """The indices of the episodes held out for validation: :data:`VALIDATION` of each outcome (at least one),
    drawn from ``seed``; none when an outcome has fewer than two episodes (nothing would be left to fit)."""
    rng = np.random.default_rng([seed, 31337])
    out: set[int] = set()
    for outcome in (False, True):
        idx = [i for i, f in enumerate(failed) if f == outcome]
        if len(idx) < 2:
            return set()
        out |= {int(i) for i in rng.choice(idx, max(1, round(VALIDATION * len(idx))), replace=False)}
    return out


def fit_sequence(
    seqs: Sequence[np.ndarray], failed: Sequence[bool], row_weight: Sequence[np.ndarray], seed: int
) -> SequenceProbe:
    """A :class:`SequenceProbe` trained on the episodes ``seqs`` (see :meth:`SequenceProbe.fit`)."""
    probe = SequenceProbe(seqs[0].shape[1], seed)
    probe.fit(seqs, failed, row_weight, seed)
    return probe
