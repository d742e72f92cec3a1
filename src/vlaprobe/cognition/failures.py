"""`vlaprobe failures`: how early and how reliably each predictor sees a stored episode fail.

The episodes are split into folds (stratified by outcome, seeded). Each fold is scored by predictors fitted on
the other folds (``vlaprobe.cognition.failure_scores``) less half of their successful episodes, which
calibrate the fold's alarm band (functional conformal prediction, split per fold: calibration and test
episodes are both unseen by the predictors that score them). Every figure has a 95% episode-bootstrap interval
(``vlaprobe.probes.bootstrap``). ``failures.json`` holds them: one writer, one reader, versioned.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from vlaprobe.cognition.failure_metrics import (
    alarm_onsets,
    at_time,
    conformal_band,
    first_alarm,
    roc_curve,
    running_mean,
    score_bands,
    weighted_auc,
    weighted_median,
)
from vlaprobe.cognition.failure_scores import FEATURES, EpisodeData, Fitted, fit, predictor_names
from vlaprobe.configs.failures import FailuresConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import from_json, read_versioned, write_atomic
from vlaprobe.probes.bootstrap import Estimate, bootstrap_weights, interval

FAILURES_FILE = "failures.json"
FORMAT, VERSION = "vlaprobe-failures", 3
READABLE = {1, 2, 3}
"""Version 1 lacks the ROC curves, the score bands and the token figures: they read as empty."""
TIMES = (0.25, 0.5, 0.75, 1.0)
"""Normalised times of the ROC-AUCs."""
STEPS = (25, 50, 100)
"""Steps of the length-free ROC-AUCs."""
BAND_TIMES = tuple(round(i / 20, 2) for i in range(21))
"""Normalised times of the score bands."""


@dataclass(frozen=True)
class Roc:
    """A ROC curve: false- and true-positive rates of every threshold, from (0, 0) to (1, 1)."""

    fpr: list[float]
    tpr: list[float]


@dataclass(frozen=True)
class Band:
    """The quartiles of a group of episodes' running scores at each of :data:`BAND_TIMES`."""

    low: list[float]
    median: list[float]
    high: list[float]


@dataclass(frozen=True)
class ScoreBands:
    """A predictor's running score over normalised time, successes against failures (out of fold)."""

    times: list[float]
    success: Band
    failure: Band


@dataclass(frozen=True)
class PredictorFigures:
    """One predictor's figures over all episodes (out of fold)."""

    name: str
    auc: dict[str, Estimate]
    """Normalised time ("0.25", ...) -> ROC-AUC of the running score there, failures against successes."""
    auc_at_step: dict[str, Estimate]
    """Step ("25", ...) -> ROC-AUC of the running score there over the episodes still running: free of the
    episodes' lengths (failures run to the step limit, successes end early), where time alone scores 0.5."""
    detection_rate: Estimate
    """Share of failed episodes with an alarm before their last row."""
    lead_to_end: Estimate
    """Median over detected failures of the steps from the first alarm to the episode's last row."""
    lead_to_failure_step: Estimate
    """Median over detected failures with a known failure step of (failure step - first alarm); > 0: before."""
    false_alarm_rate: Estimate
    """Share of successful episodes with an alarm (the conformal band's target: alpha)."""
    false_alarms_per_100_steps: Estimate
    """Alarms raised (rows crossing the band) per 100 rows of successful episodes."""
    alarm_drivers: dict[str, int]
    """cognition only: the feature with the largest term at each first alarm, and "rule:<id>" for each rule
    violated then, counted over alarmed episodes."""
    alarms: list[AlarmCause] = field(default_factory=list)
    """cognition only: each alarmed episode's first alarm and what drove it (format 3; empty before)."""
    roc: dict[str, Roc] = field(default_factory=dict)
    """Normalised time -> the ROC curve of the running score there (its area is ``auc``)."""
    bands: ScoreBands | None = None
    """The running score's median and interquartile band over time, successes and failures."""


@dataclass(frozen=True)
class AlarmCause:
    """What drove the cognition's first alarm in one episode."""

    key: str
    row: int
    failed: bool
    feature: str
    """The feature with the largest term in the score at that row."""
    rules: list[str]
    """The rules violated at that row."""
    atoms: list[str]
    """The beliefs involved: the violated rules' atoms, then the subgoal not yet done (its belief)."""
    event: str
    """The latest regression or drop up to that row ("" for none)."""


@dataclass(frozen=True)
class FailuresResult:
    """What `vlaprobe failures` measured."""

    store: str
    episodes: int
    failed: int
    known_failure_steps: int
    atoms: str
    """"truth" (stored atoms) or the probe folder the cognition read."""
    layer: int
    alpha: float
    folds: int
    calibration_episodes: int
    """The fewest successful calibration episodes of a fold's band; below 1/alpha - 1 the band is infinite
    (no alarm can be controlled at that alpha)."""
    token_uncertainty: str
    """How token uncertainty was scored (the model that recomputed it), or why it was not."""
    predictors: list[PredictorFigures]
    cognition_coefficients: dict[str, float]
    """The cognition score's coefficients (standardised features), fitted on every episode."""
    token_match: float | None = None
    """Share of steps whose recomputed greedy action tokens equal the stored ones (None: not recomputed): 1.0
    says the recomputed distributions are the ones the observer chose its tokens from."""


def _fig(value: float, resampled: np.ndarray) -> Estimate:
    low, high = interval(resampled)

    def clean(x: float) -> float | None:
        return None if not np.isfinite(x) else round(float(x), 4)

    return Estimate(clean(value), clean(low), clean(high))


NO_TOKENS = (
    "not scored: the store keeps the action token ids, not their probabilities; --token-model (the store's observer)"
    " recomputes them from the stored images"
)


@dataclass(frozen=True)
class TokenSource:
    """Where the episodes' action-token distributions came from."""

    how: str
    match: float
    """Share of steps whose recomputed greedy tokens equal the stored ones."""


@dataclass
class _Scored:
    """One predictor's out-of-fold running scores and band of every episode."""

    running: list[np.ndarray]
    bands: list[np.ndarray]
    alarms: list[int | None]


def folds_of(failed: np.ndarray, folds: int, seed: int) -> np.ndarray:
    """Fold index of every episode, outcomes spread evenly over the folds."""
    rng = np.random.default_rng([seed, 57])
    fold = np.zeros(len(failed), np.int64)
    for outcome in (False, True):
        idx = np.flatnonzero(failed == outcome)
        fold[rng.permutation(idx)] = np.arange(len(idx)) % folds
    return fold


def calibration_sets(failed: np.ndarray, fold: np.ndarray, seed: int) -> list[np.ndarray]:
    """Per fold k: half (rounded up) of the other folds' successful episodes, drawn by the seed; they calibrate
    fold k's band and are left out of its predictors' training."""
    rng = np.random.default_rng([seed, 61])
    out = []
    for k in range(int(fold.max()) + 1):
        wins = rng.permutation(np.flatnonzero((fold != k) & ~failed))
        out.append(np.sort(wins[: -(-len(wins) // 2)]))
    return out


def score_folds(
    data: list[EpisodeData], fold: np.ndarray, alpha: float, seed: int
) -> tuple[dict[str, _Scored], list[Fitted], int]:
    """Running scores, bands and first alarms of every predictor for every episode, from the predictors of
    its fold (split conformal per fold: calibration and test episodes are both unseen by those predictors);
    also the fewest calibration episodes of a fold."""
    failed = np.array([e.failed for e in data])
    cals = calibration_sets(failed, fold, seed)
    fits, names = [], predictor_names(data)
    for k, cal in enumerate(cals):
        train = [e for i, (e, f) in enumerate(zip(data, fold, strict=True)) if f != k and i not in set(cal)]
        fits.append(fit(train, seed))
    length = max(e.length for e in data)
    out = {}
    for p in names:
        bands = [
            conformal_band([running_mean(fits[k].score(p, data[i])) for i in cal], alpha, length)
            for k, cal in enumerate(cals)
        ]
        running = [running_mean(fits[f].score(p, e)) for e, f in zip(data, fold, strict=True)]
        per = [bands[f] for f in fold]
        out[p] = _Scored(running, per, [first_alarm(r, b) for r, b in zip(running, per, strict=True)])
    return out, fits, min(len(c) for c in cals)


def _causes(data: list[EpisodeData], fits: list[Fitted], fold: np.ndarray, s: _Scored) -> list[AlarmCause]:
    """The cognition's first alarm of every alarmed episode and what drove it."""
    out = []
    for e, f, row in zip(data, fold, s.alarms, strict=True):
        if row is None:
            continue
        terms = fits[f].contributions(e)[row]
        atoms = list(e.violated_atoms[row]) if e.violated_atoms is not None else []
        atoms += [e.subgoal[row]] if e.subgoal[row] and e.subgoal[row] not in atoms else []
        event = e.last_event[row] if e.last_event is not None else ""
        feature = FEATURES[int(np.argmax(terms))]
        out.append(AlarmCause(e.key, int(row), e.failed, feature, list(e.rules[row]), atoms, event))
    return out


def _drivers(causes: list[AlarmCause]) -> dict[str, int]:
    """Per feature and "rule:<id>", the first alarms it drove."""
    counts: Counter[str] = Counter(c.feature for c in causes)
    counts.update(f"rule:{r}" for c in causes for r in c.rules)
    return dict(sorted(counts.items()))


def predictor_figures(
    name: str,
    data: list[EpisodeData],
    s: _Scored,
    weights: np.ndarray,
    causes: list[AlarmCause] | None = None,
) -> PredictorFigures:
    """The figures of one predictor, with intervals over the bootstrap ``weights`` (resamples, episodes)."""
    failed = np.array([e.failed for e in data])
    auc, roc = {}, {}
    for tau in TIMES:
        x = at_time(s.running, tau)
        auc[f"{tau:g}"] = _fig(
            weighted_auc(x, failed), np.array([weighted_auc(x, failed, w) for w in weights])
        )
        roc[f"{tau:g}"] = Roc(*(list(np.round(v, 4)) for v in roc_curve(x, failed)))
    groups = [
        [r for r, f in zip(s.running, failed, strict=True) if f == outcome] for outcome in (False, True)
    ]
    bands = ScoreBands(list(BAND_TIMES), *(Band(*score_bands(g, BAND_TIMES)) for g in groups))
    at_step = {}
    for step in STEPS:
        alive = np.array([e.length > step for e in data])
        x = np.array([r[step] if e.length > step else 0.0 for r, e in zip(s.running, data, strict=True)])
        at_step[str(step)] = _fig(
            weighted_auc(x[alive], failed[alive]),
            np.array([weighted_auc(x[alive], failed[alive], w[alive]) for w in weights]),
        )
    last = np.array([e.length - 1 for e in data])
    alarmed = np.array([a is not None and a < n for a, n in zip(s.alarms, last, strict=True)])
    fails, wins = failed.astype(float), (~failed).astype(float)

    def share(mask: np.ndarray, of: np.ndarray) -> Estimate:
        num, den = weights @ (mask * of), weights @ of
        with np.errstate(invalid="ignore", divide="ignore"):
            return _fig(float((mask * of).sum() / max(of.sum(), 1)), np.where(den > 0, num / den, np.nan))

    def median(values: np.ndarray, keep: np.ndarray) -> Estimate:
        v = np.where(keep, values, 0.0)
        return _fig(
            weighted_median(v[keep], np.ones(int(keep.sum()))),
            np.array([weighted_median(v[keep], w[keep]) for w in weights]),
        )

    first = np.array([a if a is not None else -1 for a in s.alarms], float)
    to_end = last - first
    fstep = np.array([e.failure_step if e.failure_step is not None else np.nan for e in data])
    known = failed & alarmed & np.isfinite(fstep)
    onsets = np.array([alarm_onsets(r, b) for r, b in zip(s.running, s.bands, strict=True)], float)
    rows = np.array([e.length for e in data], float)
    per100 = 100 * (weights @ (onsets * wins)) / np.maximum(weights @ (rows * wins), 1)
    return PredictorFigures(
        name=name,
        auc=auc,
        auc_at_step=at_step,
        detection_rate=share(alarmed, fails),
        lead_to_end=median(to_end, failed & alarmed),
        lead_to_failure_step=median(np.nan_to_num(fstep) - first, known),
        false_alarm_rate=share(alarmed, wins),
        false_alarms_per_100_steps=_fig(100 * (onsets * wins).sum() / max((rows * wins).sum(), 1), per100),
        alarm_drivers=_drivers(causes) if causes is not None else {},
        alarms=list(causes or []),
        roc=roc,
        bands=bands,
    )


def evaluate(
    data: list[EpisodeData], cfg: FailuresConfig, atoms: str, layer: int, tokens: TokenSource | None = None
) -> FailuresResult:
    """Every predictor's figures on ``data`` (needs failed and successful episodes); ``tokens``: where the
    episodes' token distributions came from, when they carry them."""
    failed = np.array([e.failed for e in data])
    if failed.sum() < cfg.folds or (~failed).sum() < cfg.folds:
        raise VlaprobeError(
            f"{int(failed.sum())} failed and {int((~failed).sum())} successful episodes; --folds {cfg.folds} needs "
            "at least that many of each: collect more with --keep-failed --expert-faults, or lower --folds"
        )
    fold = folds_of(failed, cfg.folds, cfg.seed)
    scored, fits, calibration = score_folds(data, fold, cfg.alpha, cfg.seed)
    weights = bootstrap_weights(len(data), cfg.bootstrap, cfg.seed)
    figures = [
        predictor_figures(
            p, data, scored[p], weights, _causes(data, fits, fold, scored[p]) if p == "cognition" else None
        )
        for p in predictor_names(data)
    ]
    whole = fit(data, cfg.seed)
    return FailuresResult(
        store=str(cfg.store),
        episodes=len(data),
        failed=int(failed.sum()),
        known_failure_steps=sum(e.failure_step is not None for e in data if e.failed),
        atoms=atoms,
        layer=layer,
        alpha=cfg.alpha,
        folds=cfg.folds,
        calibration_episodes=calibration,
        token_uncertainty=NO_TOKENS if tokens is None else tokens.how,
        predictors=figures,
        cognition_coefficients={f: round(float(c), 4) for f, c in zip(FEATURES, whole.coef, strict=True)},
        token_match=None if tokens is None else tokens.match,
    )


def write_failures(folder: str | Path, result: FailuresResult) -> Path:
    """Write ``failures.json`` into ``folder`` (the one writer)."""
    path = Path(folder) / FAILURES_FILE
    data = {"format": FORMAT, "format_version": VERSION, **asdict(result)}
    write_atomic(path, json.dumps(data, indent=1, allow_nan=False) + "\n")
    return path


def read_failures(folder: str | Path) -> FailuresResult:
    """Read ``failures.json`` from ``folder`` (the one reader)."""
    path = Path(folder) / FAILURES_FILE
    hint = "run `vlaprobe failures` again"
    data, _ = read_versioned(path, FORMAT, "failure-prediction file", READABLE, hint)
    body = {k: v for k, v in data.items() if k not in ("format", "format_version")}
    return from_json(FailuresResult, body, path, hint)


def main(cfg: FailuresConfig) -> int:
    """Run the evaluation, write ``failures.json`` into ``--out`` and print the figures."""
    from vlaprobe.cognition.failures_load import load_episodes
    from vlaprobe.cognition.failures_report import table
    from vlaprobe.files import check_output_folder

    if not 0 < cfg.alpha < 1:
        raise VlaprobeError(f"--alpha must be between 0 and 1, got {cfg.alpha}")
    if cfg.folds < 2 or cfg.bootstrap < 1:
        raise VlaprobeError("--folds needs at least 2 and --bootstrap at least 1")
    check_output_folder(cfg.out)
    data, atoms, layer, tokens = load_episodes(cfg)
    result = evaluate(data, cfg, atoms, layer, tokens)
    path = write_failures(cfg.out, result)
    print(json.dumps(asdict(result)) if cfg.json else f"{table(result)}\nwrote {path}")
    return 0
