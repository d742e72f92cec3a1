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
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vlaprobe.cognition.failure_metrics import (
    alarm_onsets,
    at_time,
    conformal_band,
    first_alarm,
    running_mean,
    weighted_auc,
    weighted_median,
)
from vlaprobe.cognition.failure_scores import FEATURES, PREDICTORS, EpisodeData, Fitted, fit
from vlaprobe.configs.failures import FailuresConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import from_json, read_versioned, write_atomic
from vlaprobe.probes.bootstrap import Estimate, bootstrap_weights, interval

if TYPE_CHECKING:
    from vlaprobe.reports.sections import Section

FAILURES_FILE = "failures.json"
FORMAT, VERSION = "vlaprobe-failures", 1
TIMES = (0.25, 0.5, 0.75, 1.0)
"""Normalised times of the ROC-AUCs."""
STEPS = (25, 50, 100)
"""Steps of the length-free ROC-AUCs."""


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
    """Why token uncertainty is not among the predictors."""
    predictors: list[PredictorFigures]
    cognition_coefficients: dict[str, float]
    """The cognition score's coefficients (standardised features), fitted on every episode."""


def _fig(value: float, resampled: np.ndarray) -> Estimate:
    low, high = interval(resampled)

    def clean(x: float) -> float | None:
        return None if not np.isfinite(x) else round(float(x), 4)

    return Estimate(clean(value), clean(low), clean(high))


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
    fits = []
    for k, cal in enumerate(cals):
        train = [e for i, (e, f) in enumerate(zip(data, fold, strict=True)) if f != k and i not in set(cal)]
        fits.append(fit(train, seed))
    length = max(e.length for e in data)
    out = {}
    for p in PREDICTORS:
        bands = [
            conformal_band([running_mean(fits[k].score(p, data[i])) for i in cal], alpha, length)
            for k, cal in enumerate(cals)
        ]
        running = [running_mean(fits[f].score(p, e)) for e, f in zip(data, fold, strict=True)]
        per = [bands[f] for f in fold]
        out[p] = _Scored(running, per, [first_alarm(r, b) for r, b in zip(running, per, strict=True)])
    return out, fits, min(len(c) for c in cals)


def _drivers(data: list[EpisodeData], fits: list[Fitted], fold: np.ndarray, s: _Scored) -> dict[str, int]:
    counts: Counter[str] = Counter()
    for e, f, row in zip(data, fold, s.alarms, strict=True):
        if row is None:
            continue
        terms = fits[f].contributions(e)[row]
        counts[FEATURES[int(np.argmax(terms))]] += 1
        counts.update(f"rule:{r}" for r in e.rules[row])
    return dict(sorted(counts.items()))


def predictor_figures(
    name: str, data: list[EpisodeData], s: _Scored, weights: np.ndarray, drivers: dict[str, int]
) -> PredictorFigures:
    """The figures of one predictor, with intervals over the bootstrap ``weights`` (resamples, episodes)."""
    failed = np.array([e.failed for e in data])
    auc = {}
    for tau in TIMES:
        x = at_time(s.running, tau)
        auc[f"{tau:g}"] = _fig(
            weighted_auc(x, failed), np.array([weighted_auc(x, failed, w) for w in weights])
        )
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
        alarm_drivers=drivers,
    )


def evaluate(data: list[EpisodeData], cfg: FailuresConfig, atoms: str, layer: int) -> FailuresResult:
    """Every predictor's figures on ``data`` (needs failed and successful episodes)."""
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
            p, data, scored[p], weights, _drivers(data, fits, fold, scored[p]) if p == "cognition" else {}
        )
        for p in PREDICTORS
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
        token_uncertainty="the store keeps the action token ids, not their probabilities: no entropy to score",
        predictors=figures,
        cognition_coefficients={f: round(float(c), 4) for f, c in zip(FEATURES, whole.coef, strict=True)},
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
    data, _ = read_versioned(path, FORMAT, "failure-prediction file", {VERSION}, hint)
    body = {k: v for k, v in data.items() if k not in ("format", "format_version")}
    return from_json(FailuresResult, body, path, hint)


def table(result: FailuresResult) -> str:
    """The figures as lines for people."""

    def f(x: Estimate) -> str:
        if x.value is None:
            return "n/a"
        return f"{x.value:.3g} [{'n/a' if x.low is None else f'{x.low:.3g}'}, {'n/a' if x.high is None else f'{x.high:.3g}'}]"

    lines = [
        f"{result.episodes} episodes, {result.failed} failed ({result.known_failure_steps} with a known failure step);"
        f" cognition on {result.atoms}, probe layer {result.layer}, alpha {result.alpha}, {result.folds} folds"
        f" (at least {result.calibration_episodes} calibration successes each)",
    ]
    for p in result.predictors:
        aucs = "  ".join(f"AUC@{t} {f(v)}" for t, v in p.auc.items())
        aucs += "  " + "  ".join(f"AUC@step{t} {f(v)}" for t, v in p.auc_at_step.items())
        lines.append(f"{p.name:10s} {aucs}")
        lines.append(
            f"{'':10s} detected {f(p.detection_rate)}  lead to end {f(p.lead_to_end)}  lead to failure step "
            f"{f(p.lead_to_failure_step)}  false-alarm rate {f(p.false_alarm_rate)}  per 100 steps "
            f"{f(p.false_alarms_per_100_steps)}"
        )
        if p.alarm_drivers:
            lines.append(f"{'':10s} alarm drivers {p.alarm_drivers}")
    lines.append(f"token uncertainty: {result.token_uncertainty}")
    return "\n".join(lines)


def report_section(probes: Path) -> Section | None:
    """The report's failure-prediction section when ``failures.json`` is in the probe folder (``vlaprobe
    failures --out`` that folder), else None; it renders ``templates/failures_section.html`` of this package."""
    if not (Path(probes) / FAILURES_FILE).is_file():
        return None
    from vlaprobe.reports.sections import Section

    data = asdict(read_failures(probes))
    return Section(
        id="failures",
        title="Failure prediction",
        template="failures_section.html",
        data=data,
        package="vlaprobe.cognition",
    )


def load_episodes(cfg: FailuresConfig) -> tuple[list[EpisodeData], str, int]:
    """Every stored episode as the predictors read it; the atoms' source and the probe's layer."""
    from vlaprobe.cognition.core import Cognition
    from vlaprobe.cognition.failure_scores import cognition_columns, run_cognition
    from vlaprobe.cognition.plan import TaskGoal, stored_task_goal
    from vlaprobe.cognition.readout import HEADS, ProbeReadout
    from vlaprobe.collection.store import ActivationStore
    from vlaprobe.collection.verify import require_intact

    store = ActivationStore.open(cfg.store)
    infos = store.episodes()
    require_intact(cfg.store, read=True, keys=[e.key for e in infos])
    layer = store.num_hidden_states // 2 if cfg.layer is None else cfg.layer
    if not 0 <= layer < store.num_hidden_states:
        raise VlaprobeError(
            f"--layer {layer} is not a hidden state of {cfg.store} (0..{store.num_hidden_states - 1})"
        )
    readout = None if cfg.probes is None else ProbeReadout.load(cfg.probes, model_id=store.model_id)
    cogs: dict[TaskGoal, Cognition] = {}
    data = []
    for info in infos:
        attrs = store.episode(info.key).attributes
        goal = stored_task_goal(store.suite, info.task, attrs, f"episode {info.key} of {cfg.store}")
        if goal not in cogs:
            probed = None if readout is None else readout.probed
            cogs[goal] = Cognition(
                store.atom_names["object"], store.atom_names["action"], goal, probed=probed
            )
        if readout is None:
            obj, act = store.labels("object", [info.key]), store.labels("action", [info.key])
        else:
            pred = readout.assign_steps({h: store.layer(readout.layers[h], [info.key]) for h in HEADS})
            obj, act = pred.values["object"], pred.values["action"]
        steps = run_cognition(cogs[goal], obj, act)
        cols, rules, subgoal = cognition_columns(steps)
        data.append(
            EpisodeData(
                key=info.key,
                task=info.task,
                failed=not info.success,
                failure_step=attrs.failure_step,
                hidden=np.asarray(store.layer(layer, [info.key]), np.float32),
                progress=np.array([s.progress for s in steps]),
                cognition=cols,
                rules=rules,
                subgoal=subgoal,
            )
        )
    return data, "truth" if cfg.probes is None else str(cfg.probes), layer


def main(cfg: FailuresConfig) -> int:
    """Run the evaluation, write ``failures.json`` into ``--out`` and print the figures."""
    from vlaprobe.files import check_output_folder

    if not 0 < cfg.alpha < 1:
        raise VlaprobeError(f"--alpha must be between 0 and 1, got {cfg.alpha}")
    if cfg.folds < 2 or cfg.bootstrap < 1:
        raise VlaprobeError("--folds needs at least 2 and --bootstrap at least 1")
    check_output_folder(cfg.out)
    data, atoms, layer = load_episodes(cfg)
    result = evaluate(data, cfg, atoms, layer)
    path = write_failures(cfg.out, result)
    print(json.dumps(asdict(result)) if cfg.json else f"{table(result)}\nwrote {path}")
    return 0
