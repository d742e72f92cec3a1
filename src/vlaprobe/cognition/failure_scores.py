"""Per-step failure scores of stored episodes: the cognition, a hidden-state failure probe, time, task × time.

Each predictor is fitted on training episodes (label: the episode failed) and scores every row of another
episode from that row and the ones before it, as a live monitor could:

- ``cognition``: a logistic regression on five features of the cognition's conclusions at the row — the
  progress deficit (the training successes' mean subgoal progress at that step minus the episode's), the stall
  length (steps since the subgoal level last changed, /100), the violations holding, and the regressions and
  drops so far. Its coefficients say which features drove an alarm.
- ``probe``: a logistic regression on one layer's hidden state of the row (standardised); ``probe_mlp``: a small
  MLP (one hidden layer of :data:`MLP_UNITS`, weight decay, early stopping) on the same states, trained by the
  same function on the same rows and weights (:func:`fit_hidden`); ``probe_lstm``: an LSTM over the layer's
  states of the rows so far (:mod:`vlaprobe.cognition.failure_sequence`), the same rows and weights.
- ``time``: the step itself. ``task_time``: the training episodes' failure share among those of the same task
  still running at that step (bins of :data:`BIN` steps).
- ``token_entropy`` and ``token_max_prob`` (only when the episodes carry them, ``EpisodeData.tokens``): the mean
  entropy of the 7 action tokens' distributions over the action bins, and minus their mean top probability,
  as the observer computed them at the row. Unsupervised: nothing is fitted.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vlaprobe.cognition.core import Cognition, CognitionStep
from vlaprobe.cognition.failure_sequence import fit_sequence

FEATURES = ("progress_deficit", "stall", "violations", "regressions", "drops")
"""The cognition's features, in column order."""
BIN = 10
"""Steps per bin of the task × time baseline."""
PREDICTORS = ("cognition", "probe", "probe_mlp", "probe_lstm", "time", "task_time")
TOKEN_PREDICTORS = ("token_entropy", "token_max_prob")
"""Scored when every episode carries its action-token distribution (``EpisodeData.tokens``)."""
MLP_UNITS = 32
"""Hidden units of the MLP failure probe."""


def predictor_names(data: Sequence[EpisodeData]) -> tuple[str, ...]:
    """The predictors ``data`` supports: the token ones when every episode carries its token distribution."""
    tokens = bool(data) and all(e.tokens is not None for e in data)
    return PREDICTORS + (TOKEN_PREDICTORS if tokens else ())


@dataclass
class EpisodeData:
    """What the predictors read of one stored episode."""

    key: str
    task: int
    failed: bool
    failure_step: int | None
    """The row from which the failure was certain (an injected fault), where known."""
    hidden: np.ndarray
    """(T, hidden) float32 at the probe's layer."""
    progress: np.ndarray
    """(T,) the cognition's subgoal progress, 0..1."""
    cognition: np.ndarray
    """(T, len(FEATURES)) with the progress deficit column 0 (filled by :func:`with_deficit`)."""
    rules: list[tuple[str, ...]]
    """Per row: the rules whose violations hold."""
    subgoal: list[str]
    """Per row: the active subgoal's belief ("" once the goal is reached)."""
    tokens: np.ndarray | None = None
    """(T, 2): the observer's mean action-token entropy and mean top probability at each row, or None."""
    violated_atoms: list[tuple[str, ...]] | None = None
    """Per row: the atoms of the violations holding (:func:`alarm_context`); None: not recorded."""
    last_event: list[str] | None = None
    """Per row: the latest regression or drop so far, its message ("" for none); None: not recorded."""

    @property
    def length(self) -> int:
        return len(self.progress)


def cognition_columns(steps: Sequence[CognitionStep]) -> tuple[np.ndarray, list[tuple[str, ...]], list[str]]:
    """The features (deficit left 0), the rules violated and the active subgoal of every step of a run."""
    cols = np.zeros((len(steps), len(FEATURES)))
    level, since, regressions, drops = -1.0, 0, 0, 0
    rules, subgoal = [], []
    for t, s in enumerate(steps):
        if s.progress != level:
            level, since = s.progress, t
        regressions += sum(e.kind == "regression" for e in s.events)
        drops += sum(e.kind == "dropped" for e in s.events)
        cols[t, 1:] = ((t - since) / 100.0, len(s.violations), regressions, drops)
        rules.append(tuple(sorted({v.rule for v in s.violations})))
        subgoal.append(next((g.name for g in s.subgoals if g.status != "done"), ""))
    return cols, rules, subgoal


def alarm_context(steps: Sequence[CognitionStep]) -> tuple[list[tuple[str, ...]], list[str]]:
    """Per step of a run: the atoms of the violations holding, and the latest regression or drop so far ("")."""
    atoms, events, last = [], [], ""
    for s in steps:
        last = next((e.message for e in reversed(s.events) if e.kind in ("regression", "dropped")), last)
        atoms.append(tuple(sorted({a for v in s.violations for a in v.atoms})))
        events.append(last)
    return atoms, events


def run_cognition(cog: Cognition, obj: np.ndarray, act: np.ndarray) -> list[CognitionStep]:
    """One episode's atoms (T, ...) through a reset cognition."""
    cog.reset()
    return [cog.step(obj[t], act[t]) for t in range(len(obj))]


def expected_progress(episodes: Sequence[EpisodeData], length: int) -> np.ndarray:
    """(length,) the successful episodes' mean progress per step (an ended one stays at its last value)."""
    wins = [e.progress for e in episodes if not e.failed]
    if not wins:
        return np.zeros(length)
    out = np.zeros((len(wins), length))
    for i, p in enumerate(wins):
        out[i, : len(p)] = p[:length]
        out[i, len(p) :] = p[-1]
    return out.mean(0)


def with_deficit(e: EpisodeData, expected: np.ndarray) -> np.ndarray:
    """The episode's cognition features with the progress deficit against ``expected``."""
    x = e.cognition.copy()
    x[:, 0] = expected[np.minimum(np.arange(e.length), len(expected) - 1)] - e.progress
    return x


@dataclass
class Fitted:
    """The predictors fitted on one fold's training episodes."""

    expected: np.ndarray
    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    intercept: float
    probes: dict[str, object]
    """"probe", "probe_mlp" -> a fitted classifier of the hidden state (:func:`fit_hidden`); "probe_lstm" -> one
    of the hidden states so far (:func:`~vlaprobe.cognition.failure_sequence.fit_sequence`)."""
    task_time: dict[tuple[int, int], float]
    base_rate: float

    def score(self, name: str, e: EpisodeData) -> np.ndarray:
        """(T,) per-step scores of predictor ``name`` for episode ``e``."""
        t = np.arange(e.length, dtype=np.float64)
        if name == "cognition":
            return self.contributions(e).sum(1) + self.intercept
        if name in self.probes:
            p = np.asarray(self.probes[name].predict_proba(e.hidden))[:, 1]  # type: ignore[attr-defined]
            p = np.clip(p, 1e-12, 1 - 1e-12)
            return np.log(p / (1 - p))  # the logit: the linear probe's decision function
        if name in TOKEN_PREDICTORS:
            if e.tokens is None:
                raise ValueError(f"episode {e.key} carries no token distribution")
            return e.tokens[:, 0] if name == "token_entropy" else -e.tokens[:, 1]
        if name == "time":
            return t
        if name == "task_time":
            bins = t.astype(int) // BIN
            return np.array([self.task_time.get((e.task, int(b)), self.base_rate) for b in bins])
        raise ValueError(name)

    def contributions(self, e: EpisodeData) -> np.ndarray:
        """(T, len(FEATURES)): each feature's term in the cognition score."""
        return (with_deficit(e, self.expected) - self.mean) / self.scale * self.coef


def balanced(y: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """``weight`` rescaled so that both classes carry the same total weight."""
    out = weight.astype(np.float64).copy()
    for c in (False, True):
        mass = out[y == c].sum()
        if mass > 0:
            out[y == c] *= 0.5 * weight.sum() / mass
    return out


def fit_hidden(kind: str, h: np.ndarray, y: np.ndarray, weight: np.ndarray, seed: int) -> object:
    """A failure probe of hidden states: standardised, then ``kind`` "probe" (logistic regression, C = 0.01)
    or "probe_mlp" (an MLP of :data:`MLP_UNITS` units); both on the same rows with the same class-balanced
    ``weight`` (episodes counted equally)."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.linear_model import LogisticRegression
    from sklearn.neural_network import MLPClassifier
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    model: object
    if kind == "probe":
        model = LogisticRegression(C=0.01, max_iter=500, random_state=seed)
    elif kind == "probe_mlp":
        model = MLPClassifier((MLP_UNITS,), alpha=0.1, max_iter=200, random_state=seed)
    else:
        raise ValueError(kind)
    pipe = make_pipeline(StandardScaler(), model)
    step = pipe.steps[-1][0]
    with warnings.catch_warnings():
        warnings.simplefilter(
            "ignore", ConvergenceWarning
        )  # max_iter bounds the MLP's time; it is scored anyway
        pipe.fit(h, y, **{f"{step}__sample_weight": balanced(y, weight)})
    return pipe


def fit(train: Sequence[EpisodeData], seed: int) -> Fitted:
    """Fit every predictor on ``train`` (both outcomes needed)."""
    from sklearn.linear_model import LogisticRegression

    length = max(e.length for e in train)
    expected = expected_progress(train, length)
    y = np.concatenate([np.full(e.length, e.failed) for e in train])
    weight = np.concatenate([np.full(e.length, 1.0 / e.length) for e in train])  # episodes count equally
    x = np.concatenate([with_deficit(e, expected) for e in train])
    mean, scale = x.mean(0), np.maximum(x.std(0), 1e-9)
    lr = LogisticRegression(C=1.0, class_weight="balanced", max_iter=1000, random_state=seed)
    lr.fit((x - mean) / scale, y, sample_weight=weight)
    h = np.concatenate([e.hidden for e in train])
    probes = {kind: fit_hidden(kind, h, y, weight, seed) for kind in ("probe", "probe_mlp")}
    rows = np.cumsum([e.length for e in train])[:-1]
    per_episode = np.split(balanced(y, weight), rows)
    seqs, failed = [e.hidden for e in train], [e.failed for e in train]
    probes["probe_lstm"] = fit_sequence(seqs, failed, per_episode, seed)
    counts: dict[tuple[int, int], list[int]] = {}
    for e in train:
        for b in range(-(-e.length // BIN)):
            counts.setdefault((e.task, b), []).append(int(e.failed))
    base = float(np.mean([e.failed for e in train]))
    task_time = {k: (sum(v) + base) / (len(v) + 1) for k, v in counts.items()}  # one pseudo-episode of prior
    return Fitted(expected, mean, scale, lr.coef_[0], float(lr.intercept_[0]), probes, task_time, base)
