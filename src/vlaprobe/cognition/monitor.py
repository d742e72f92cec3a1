"""`vlaprobe cognition`: measure the cognition on stored episodes, fed by ground truth and by the probes.

Each episode (default: the probes' held-out test episodes) runs twice through a fresh :class:`Cognition`: on
the stored ground-truth atoms and on the probes' predictions (each head at its default layer, not-probed atoms at
their training majority). The figures compare the two runs step by step; ``monitor.json`` holds them with the
per-rule and per-episode details.

Episodes whose goal no atom can follow are left out, and probes without an action head read its atoms as unknown;
both are listed in ``monitor.json`` and printed (:meth:`MonitorResult.gaps`), never dropped in silence. In a
union store, the atoms an episode leaves undefined (``collection.defined``) are false in both runs and left out
of the agreement figures.

Counting: a violation is counted once when it appears (not once per step it lasts); flips are changes of a
probed atom between consecutive steps, before (raw predictions) and after debouncing (beliefs).
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vlaprobe.cognition.core import Cognition, CognitionStep
from vlaprobe.cognition.monitor_inputs import (
    SkippedEpisode,
    check_new_episodes,
    check_store,
    episode_goal,
    identity,
    load_readout,
)
from vlaprobe.cognition.monitor_result import (  # the result's names, also importable from here
    MONITOR_FILE,
    MONITOR_FORMAT,
    MONITOR_FORMAT_VERSION,
    EpisodeFigures,
    GoalDetection,
    MonitorResult,
    ProbeFigures,
    ViolationFigures,
    read_monitor,
    write_monitor,
)
from vlaprobe.cognition.plan import TaskGoal
from vlaprobe.cognition.readout import HEADS, ProbeReadout
from vlaprobe.collection.defined import only_defined
from vlaprobe.configs.monitor import CognitionConfig, MonitorConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.bootstrap import bootstrap_weights, interval, resample_sums

if TYPE_CHECKING:
    from vlaprobe.collection.store import ActivationStore
    from vlaprobe.probes.probeset import ProbeSet
    from vlaprobe.reports.sections import Section

__all__ = [  # with the result's names (vlaprobe.cognition.monitor_result), importable from here as before
    "MONITOR_FILE",
    "MONITOR_FORMAT",
    "MONITOR_FORMAT_VERSION",
    "EpisodeFigures",
    "GoalDetection",
    "MonitorResult",
    "ProbeFigures",
    "ViolationFigures",
    "gain_interval",
    "goal_detection",
    "main",
    "monitor",
    "read_monitor",
    "report_section",
    "write_monitor",
]


@dataclass
class _Run:
    """Per-step record of one cognition run over one episode."""

    steps: list[CognitionStep]
    beliefs: np.ndarray  # (T, atoms) bool

    @property
    def goal_step(self) -> int | None:
        return next((s.t for s in self.steps if s.goal_reached), None)

    def active(self) -> np.ndarray:
        return np.array([next((g.index for g in s.subgoals if g.status != "done"), 5) for s in self.steps])

    def new_violations(self) -> Counter[str]:
        return Counter(v.rule for s in self.steps for v in s.violations if v.since == s.t)

    def goal_events(self) -> list[int]:
        return [e.t for s in self.steps for e in s.events if e.kind == "goal_reached"]


def _run(cog: Cognition, obj: np.ndarray, act: np.ndarray) -> _Run:
    cog.reset()
    steps, beliefs = [], np.zeros((len(obj), len(cog.atoms)), dtype=bool)
    for t in range(len(obj)):
        steps.append(cog.step(obj[t], act[t]))
        beliefs[t] = cog.beliefs.values
    return _Run(steps, beliefs)


def _episodes(cfg: MonitorConfig, store: ActivationStore, probes: ProbeSet) -> tuple[list[str], bool]:
    from vlaprobe.probes.results import read_test_episodes

    keys = [e.key for e in store.episodes()]
    if cfg.all_episodes:
        return keys, False
    test = read_test_episodes(cfg.probes)
    chosen = [k for k in test if k in set(keys)]
    if not chosen:
        raise VlaprobeError(
            f"none of the probes' test episodes is in store {cfg.store}; pass the store the probes were "
            "trained on, or --all-episodes"
        )
    return chosen, not probes.refit_on_all


def _ratio(a: float, b: float) -> float | None:
    return None if b == 0 else a / b


@dataclass
class _Pair:
    """One episode run on truth and on the predictions, with the raw (not debounced) probed predictions."""

    key: str
    truth: _Run
    probes: _Run
    raw: np.ndarray  # (T, probed atoms) bool
    defined: np.ndarray  # (atoms,) bool: the atoms defined in the episode (the others are left out)


def _pair(
    store: ActivationStore,
    key: str,
    goal: TaskGoal,
    readout: ProbeReadout,
    ccfg: CognitionConfig,
    cogs: dict,
    mask: np.ndarray,
) -> _Pair:
    """Run one stored episode through the cognition on truth and on the probes' predictions."""
    if goal not in cogs:
        obj_atoms, act_atoms = store.atom_names["object"], store.atom_names["action"]
        unknown = [a for h in readout.unknown for a in readout.atoms[h]]
        cogs[goal] = (
            Cognition(obj_atoms, act_atoms, goal, ccfg),
            Cognition(obj_atoms, act_atoms, goal, ccfg, probed=readout.probed, unknown=unknown),
        )
    cog_truth, cog_probes = cogs[goal]
    defined = store.episode_defined(key)
    labels = only_defined({h: store.labels(h, [key]) for h in HEADS}, defined)
    truth = _run(cog_truth, labels["object"], labels["action"])
    pred = readout.assign_steps({h: store.layer(layer, [key]) for h, layer in readout.layers.items()})
    values = only_defined(pred.values, defined)
    run = _run(cog_probes, values["object"], values["action"])
    raw = np.concatenate([values["object"], values["action"]], axis=1)[:, mask]
    return _Pair(key, truth, run, raw, np.concatenate([defined[h] for h in HEADS]))


def _episode_figures(p: _Pair) -> EpisodeFigures:
    truth_at_goal = np.array([s.goal_reached for s in p.truth.steps])
    false_alarms = sum(1 for t in p.probes.goal_events() if not truth_at_goal[t])
    return EpisodeFigures(
        p.key,
        len(p.truth.steps),
        p.truth.goal_step,
        p.probes.goal_step,
        false_alarms,
        sum(p.truth.new_violations().values()),
        sum(p.probes.new_violations().values()),
        float((p.truth.active() == p.probes.active()).mean()),
    )


def goal_detection(episodes: list[EpisodeFigures]) -> GoalDetection:
    """Goal detection over episodes: precision and recall of "the goal was reached", delay, false alarms."""
    goals = [(e.goal_step_truth, e.goal_step_probes) for e in episodes]
    both = [(a, b) for a, b in goals if a is not None and b is not None]
    steps = sum(e.steps for e in episodes)
    return GoalDetection(
        precision=_ratio(len(both), sum(b is not None for _, b in goals)),
        recall=_ratio(len(both), sum(a is not None for a, _ in goals)),
        mean_delay_steps=float(np.mean([b - a for a, b in both])) if both else None,
        false_alarms_per_100_steps=None
        if not steps
        else 100.0 * sum(e.false_alarms for e in episodes) / steps,
        episodes=len(episodes),
        failed_episodes=sum(a is None for a, _ in goals),
    )


def gain_interval(
    agree: np.ndarray, baseline: np.ndarray, cells: np.ndarray, resamples: int = 1000, seed: int = 0
) -> tuple[float, float] | None:
    """95% percentile-bootstrap interval over episodes of (sum agree - sum baseline) / sum cells, from
    per-episode counts (the episode bootstrap of ``vlaprobe.probes.bootstrap``); None without episodes."""
    if len(cells) == 0 or cells.sum() == 0:
        return None
    weights = bootstrap_weights(len(cells), resamples, seed)
    sums = resample_sums(weights, np.stack([agree, baseline, cells], 1).astype(np.float64))
    gain = (sums[:, 0] - sums[:, 1]) / np.maximum(sums[:, 2], 1)
    return interval(gain)


def _figures(pairs: list[_Pair], mask: np.ndarray, rules: list[str]) -> tuple[ViolationFigures, ProbeFigures]:
    """The truth run's and the probe run's figures over all episodes."""
    steps = sum(len(p.truth.steps) for p in pairs)
    per100 = 100.0 / max(steps, 1)
    truth_v: Counter[str] = sum((p.truth.new_violations() for p in pairs), Counter())
    probe_v: Counter[str] = sum((p.probes.new_violations() for p in pairs), Counter())
    agree_sub = sum(int((p.truth.active() == p.probes.active()).sum()) for p in pairs)
    scored = [(p, mask & p.defined) for p in pairs]  # probed atoms defined in the episode: the scored cells
    agree_ep = np.array([int((p.truth.beliefs[:, m] == p.probes.beliefs[:, m]).sum()) for p, m in scored])
    still_ep = np.array([int((p.truth.beliefs[:, m] == p.truth.beliefs[:1, m]).sum()) for p, m in scored])
    cells_ep = np.array([len(p.truth.steps) * int(m.sum()) for p, m in scored])
    agree, cells = int(agree_ep.sum()), int(cells_ep.sum())
    raw_flips = sum(int((p.raw[1:] != p.raw[:-1]).sum()) for p in pairs)
    belief_flips = sum(int((p.probes.beliefs[1:, mask] != p.probes.beliefs[:-1, mask]).sum()) for p in pairs)
    flip_steps = max(steps - len(pairs), 1)
    truth = ViolationFigures(sum(truth_v.values()) * per100, {r: truth_v.get(r, 0) for r in rules})
    probes = ProbeFigures(
        sum(probe_v.values()) * per100,
        {r: probe_v.get(r, 0) for r in rules},
        goal_detection=goal_detection([_episode_figures(p) for p in pairs]),
        subgoal_accuracy=agree_sub / max(steps, 1),
        belief_agreement=agree / max(cells, 1),
        belief_agreement_step0=int(still_ep.sum()) / max(cells, 1),
        belief_agreement_gain_95=gain_interval(agree_ep, still_ep, cells_ep),
        flips_per_step=raw_flips / flip_steps,
        flips_per_step_debounced=belief_flips / flip_steps,
    )
    return truth, probes


def monitor(cfg: MonitorConfig) -> MonitorResult:
    """Run the cognition over the episodes on truth and on predictions; write ``monitor.json``."""
    from vlaprobe.collection.store import ActivationStore
    from vlaprobe.collection.verify import require_intact
    from vlaprobe.files import check_output_folder

    if cfg.out is not None:
        check_output_folder(cfg.out)  # before the episodes are run, not after
    store = ActivationStore.open(cfg.store)
    readout = load_readout(Path(cfg.probes), store)
    check_store(store, readout, cfg.store)  # the suite, then the model, then the atoms
    keys, held_out = _episodes(cfg, store, readout.probes)
    require_intact(cfg.store, read=True, keys=keys)  # a missing chunk would read as fill values
    sources = [(store, keys, str(cfg.store), "")]
    seen = {identity(e): str(cfg.store) for e in store.episodes()}
    for path in cfg.extra_stores:
        extra = ActivationStore.open(path)
        check_store(extra, readout, path)
        check_new_episodes(extra, path, seen, cfg.store)
        require_intact(path, read=True, keys=[e.key for e in extra.episodes()])
        sources.append((extra, [e.key for e in extra.episodes()], str(path), f"{Path(path).name}/"))
    ccfg = cfg.cognition()
    cogs: dict[TaskGoal, tuple[Cognition, Cognition]] = {}
    mask = np.concatenate([readout.probed[h] for h in HEADS])
    pairs, skipped = [], []
    for st, ks, label, prefix in sources:
        for key in ks:
            goal = episode_goal(st, key, label)
            if isinstance(goal, SkippedEpisode):
                skipped.append(replace(goal, key=prefix + key))
                continue
            pair = _pair(st, key, goal, readout, ccfg, cogs, mask)
            pair.key = prefix + key
            pairs.append(pair)
    if not pairs and skipped:
        raise VlaprobeError(
            f"the cognition can follow none of the {len(skipped)} episodes' goals ({skipped[0].reason}); "
            "collect tasks whose goals it follows (--tasks)"
        )
    engine = next(iter(cogs.values()))[0].rules if cogs else None
    rules = sorted(engine.messages) if engine is not None else []
    truth, probes = _figures(pairs, mask, rules)
    result = MonitorResult(
        episodes=len(pairs),
        steps=sum(len(p.truth.steps) for p in pairs),
        truth=truth,
        probes=probes,
        held_out=held_out,
        layers=dict(readout.layers),
        debounce=ccfg.debounce,
        rules=[str(p) for p in engine.files] if engine is not None else [],
        per_episode=[_episode_figures(p) for p in pairs],
        skipped=skipped,
        unknown_heads=list(readout.unknown),
    )
    out = Path(cfg.out) if cfg.out is not None else Path(cfg.probes)
    write_monitor(out, result)
    return result


SECTION_ID, SECTION_TITLE, SECTION_TEMPLATE = (
    "cognition",
    "Cognition: beliefs, rules and subgoals",
    "monitor_section.html",
)


def report_section(probes: Path) -> Section | None:
    """The report's cognition section (``write_report(cfg, sections=[...])``): the monitor's figures when
    ``monitor.json`` is in the probe folder, else None. The report renders ``templates/monitor_section.html``
    of this package; this is the only way the section is rendered."""
    path = Path(probes) / MONITOR_FILE
    if not path.is_file():
        return None
    from vlaprobe.reports.sections import Section

    data = read_monitor(probes).to_json()
    return Section(
        id=SECTION_ID, title=SECTION_TITLE, template=SECTION_TEMPLATE, data=data, package="vlaprobe.cognition"
    )


def main(cfg: MonitorConfig) -> int:
    """CLI entry: run :func:`monitor`, print the summary (JSON with --json), return the exit status."""
    result = monitor(cfg)
    for line in result.gaps():
        print(line, file=sys.stderr if cfg.json else sys.stdout)
    if cfg.json:
        print(json.dumps(result.summary()))
        return 0
    t, p = result.truth, result.probes
    where = "held-out test" if result.held_out else "stored"
    print(f"{result.episodes} {where} episodes, {result.steps} steps, debounce {result.debounce}")
    print(
        f"violations per 100 steps: truth {t.violations_per_100_steps:.2f}, probes {p.violations_per_100_steps:.2f}"
    )
    for rule in t.violations:
        print(f"  {rule:24s} truth {t.violations[rule]:6d}  probes {p.violations[rule]:6d}")
    g = p.goal_detection
    print(
        f"goal detection over {g.episodes} episodes ({g.failed_episodes} failed): precision {g.precision}, "
        f"recall {g.recall}, false alarms per 100 steps {g.false_alarms_per_100_steps}, "
        f"mean delay {g.mean_delay_steps} steps"
    )
    gain = p.belief_agreement_gain_95
    span = "" if gain is None else f", gain 95% [{gain[0]:+.3f}, {gain[1]:+.3f}]"
    print(
        f"subgoal accuracy {p.subgoal_accuracy:.3f}, belief agreement {p.belief_agreement:.3f} "
        f"(keeping the step-0 state: {p.belief_agreement_step0:.3f}{span}), flips per step "
        f"{p.flips_per_step:.2f} raw / {p.flips_per_step_debounced:.2f} debounced"
    )
    return 0
