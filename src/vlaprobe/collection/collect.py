"""``vlaprobe collect``: run episodes until each task has enough successful ones, record them into a store.

Reading order: :func:`collect` validates the config, asks a worker to describe the model and the suite,
opens (or creates) the store, plans from the outcomes already stored (:class:`~vlaprobe.collection.plan.Plan`),
then loops: launch units on free workers, write each finished episode into the store's staging area, and
publish or drop it as soon as the plan decides. Killing the process at any moment loses at most the
episodes in flight; rerunning the same command resumes and ends with the same episodes.
"""

from __future__ import annotations

import dataclasses
import shlex
import shutil
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from tqdm import tqdm

from vlaprobe.collection.executors import Executor, MakeWorker, make_executor
from vlaprobe.collection.plan import Plan, Unit
from vlaprobe.collection.store import EpisodeInfo, list_infos, read_meta
from vlaprobe.collection.verify import require_intact
from vlaprobe.collection.worker import EpisodeResult, RunDescription, Worker, unit_seed
from vlaprobe.collection.writer import LAYOUTS, StagedEpisode, StoreWriter, check_compatible
from vlaprobe.configs import config_to_dict
from vlaprobe.configs.checks import check_collect
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.envs.setup import resolve_assets
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject, check_output_folder, versions
from vlaprobe.locks import FolderLock, lock_folder
from vlaprobe.rollout.faults import FaultSpec
from vlaprobe.rollout.perturb import PerturbSpec

VOLATILE_MODEL_KEYS = ("device", "source")
"""Model description entries that may change between runs of one store (recorded per run, not compared)."""


@dataclass
class CollectResult:
    """What a run did (also printed)."""

    path: Path
    kept: dict[int, tuple[int, int]]
    """Task -> (successful episodes, tries) in the store's serial prefix after this run."""
    exhausted: list[int]
    """Tasks whose try budget ran out before enough successes."""
    episodes_run: int = 0
    """Episodes run by this process (including speculative ones later dropped)."""
    steps: int = 0
    """Steps of those episodes."""
    episode_seconds: float = 0.0
    """Their step-loop wall time, summed over workers."""
    label_seconds: float = 0.0
    """Of which: world-state snapshots and detectors."""
    write_seconds: float = 0.0
    """Time the parent spent writing and publishing."""
    simulators_built: int = 0
    """Simulators the workers built for this run's episodes (the one built to describe the suite aside)."""
    build_seconds: float = 0.0
    """Their build time, summed over workers."""
    wall_seconds: float = 0.0
    published: list[str] = field(default_factory=list)
    """Keys of the episodes this run added."""


def check_collect_suite(cfg: CollectConfig, prefix: str = "") -> None:
    """What ``check_collect`` cannot see from the config alone: the selected tasks exist in the suite, their
    BDDL lets ``--inits sampled`` place the objects, and ``--perturb`` parses."""
    from vlaprobe.envs.checks import check_inits, check_tasks
    from vlaprobe.rollout.perturb import PerturbSpec

    known = check_tasks(cfg.tasks, cfg.env.suite, f"--{prefix}tasks")
    check_inits(cfg.env, cfg.tasks)
    PerturbSpec.parse(cfg.perturb, f"--{prefix}perturb")
    FaultSpec.parse(cfg.expert_faults, f"--{prefix}expert-faults")
    if cfg.env.suite != "libero_spatial":  # every LIBERO-spatial goal is the rim pick's
        from vlaprobe.experts.planner import check_tasks_plannable

        expert = cfg.driver != "policy" or cfg.intervention.takeover != "none"  # a takeover hands over to it
        check_tasks_plannable(
            cfg.env,
            cfg.tasks or tuple(known),
            expert=expert,
            perturb=bool(cfg.perturb),
            chosen=bool(cfg.tasks),
            flag=f"--{prefix}tasks",
        )


def _validate(cfg: CollectConfig) -> None:
    """What collection needs beyond the range checks of ``check_collect``."""
    if not cfg.env.render:
        raise VlaprobeError("collect needs the camera image for the model; drop --env.no-render")
    if len(set(cfg.tasks)) != len(cfg.tasks):
        raise VlaprobeError(f"--tasks lists a task twice: {list(cfg.tasks)}")


def _env_meta(cfg: CollectConfig) -> JsonObject:
    """Simulator settings that change the recorded data (the assets folder may move between machines)."""
    return {
        "image_size": cfg.env.image_size,
        "settle_steps": cfg.env.settle_steps,
        "max_steps": cfg.env.max_steps,
    }


def _run_meta(cfg: CollectConfig) -> JsonObject:
    """The settings an existing store must share (:data:`~vlaprobe.collection.writer.DEFINING`), known before
    any model is loaded. Perturbations, the DAgger beta and the layouts only when used: a store without them
    reads as having their defaults."""
    extra: JsonObject = {}
    if cfg.env.inits != "fixed":
        extra["layouts"] = LAYOUTS
    if cfg.perturb:
        extra["perturb"] = PerturbSpec.parse(cfg.perturb).text()
    if cfg.expert_faults:
        extra["expert_faults"] = FaultSpec.parse(cfg.expert_faults).text()
    if cfg.driver == "dagger":
        extra["dagger_beta"] = cfg.dagger_beta
    if cfg.intervention.takeover != "none":
        extra["takeover"] = cfg.intervention.text()
    return {
        **extra,
        "driver": cfg.driver,
        "pooling": cfg.policy.pooling,
        "suite": cfg.env.suite,
        "env": _env_meta(cfg),
        "seed": cfg.policy.seed,
        "post_success_steps": cfg.post_success_steps,
        "inits": cfg.env.inits,
        "first_init": cfg.first_init,
        "keep_failed": cfg.keep_failed,
    }


def _store_meta(cfg: CollectConfig, desc: RunDescription) -> JsonObject:
    model = {k: v for k, v in desc.model.items() if k not in VOLATILE_MODEL_KEYS}
    return {
        **_run_meta(cfg),
        "atom_names": desc.atom_names,
        "model_id": desc.model_id,
        "model": model,
        "num_hidden_states": desc.num_hidden_states,
        "hidden_size": desc.hidden_size,
        "pooling": desc.pooling,
        "instructions": {str(k): v for k, v in sorted(desc.tasks.items())},
        "num_init_states": desc.num_init_states,
        "versions": versions(),
        "command": shlex.join(sys.argv),
        "config": config_to_dict(cfg),
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "runs": [],
    }


class _Progress:
    """The progress bar: kept successes out of the target, per-task counts, success rate, steps/s, ETA."""

    def __init__(self, cfg: CollectConfig, plan: Plan) -> None:
        self.plan, self.per_task = plan, cfg.episodes_per_task
        done = self._done()
        self.bar = tqdm(
            total=self.per_task * len(plan.tasks),
            initial=done,
            desc="episodes",
            unit="ep",
            disable=not cfg.progress,
            file=sys.stderr,
            dynamic_ncols=True,
        )
        self.start = time.perf_counter()
        self.steps = self.tries = self.successes = 0

    def _done(self) -> int:
        return sum(min(self.per_task, self.plan.kept(t)[0]) for t in self.plan.tasks)

    def finished(self, result: EpisodeResult) -> None:
        self.steps += result.info.length
        self.tries += 1
        self.successes += result.info.success
        rate = self.steps / max(1e-9, time.perf_counter() - self.start)
        per_task = " ".join(str(self.plan.kept(t)[0]) for t in self.plan.tasks)
        self.bar.set_postfix_str(
            f"tasks [{per_task}] ok {self.successes}/{self.tries} {rate:.1f} steps/s", refresh=False
        )
        self.bar.update(self._done() - self.bar.n)

    def close(self) -> None:
        self.bar.close()


def collect(cfg: CollectConfig, make_worker: MakeWorker = Worker) -> CollectResult:
    """Collect episodes into ``cfg.out`` (see the module docstring). ``make_worker`` builds each worker."""
    check_collect(cfg)
    check_collect_suite(cfg)
    _validate(cfg)
    cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, layout_seed=cfg.policy.seed))
    out = Path(cfg.out)
    check_output_folder(out)  # a file or an unwritable path fails here, not after the model has loaded
    resolve_assets(cfg.env.assets, cfg.env.suite)  # bad LIBERO assets fail before the model loads
    with lock_folder(out) as lock:
        was_folder = out.is_dir()
        existed = was_folder and any(out.iterdir())
        if existed:  # fail fast, before any model is loaded
            check_compatible(out, read_meta(out, "choose a new or empty folder for --out"), _run_meta(cfg))
            require_intact(out)  # a damaged episode would otherwise block or poison the resume
        try:
            result = _collect(cfg, make_worker, lock)
        except BaseException:
            if not existed:
                _remove_if_empty(out, was_folder)
            raise
    _report(cfg, result)
    return result


def _remove_if_empty(out: Path, was_folder: bool) -> None:
    """Remove the store this run created when it holds no episode and no failure mark (a refused or failed
    run leaves nothing behind); the folder itself stays if it was there before, empty."""
    if not out.is_dir() or list_infos(out / "episodes") or list_infos(out / "failures"):
        return
    if not was_folder:
        shutil.rmtree(out)
        return
    for entry in out.iterdir():
        shutil.rmtree(entry) if entry.is_dir() else entry.unlink()


def _collect(cfg: CollectConfig, make_worker: MakeWorker, lock: FolderLock) -> CollectResult:
    """The run itself, under the store's lock: describe, open the store, plan, loop."""
    start = time.perf_counter()
    out = Path(cfg.out)
    executor = make_executor(cfg, make_worker)
    writer: StoreWriter | None = None
    progress: _Progress | None = None
    try:
        desc = executor.describe()
        tasks = list(cfg.tasks) or sorted(desc.tasks)
        unknown = [t for t in tasks if t not in desc.tasks]
        if unknown:
            raise VlaprobeError(
                f"--tasks {unknown} do not exist; {cfg.env.suite} has tasks 0-{max(desc.tasks)} (see `vlaprobe tasks`)"
            )
        left = desc.num_init_states - cfg.first_init
        if left < 1:
            raise VlaprobeError(
                f"--first-init {cfg.first_init} leaves no init state; the tasks have {desc.num_init_states} "
                f"(0-{desc.num_init_states - 1})"
            )
        writer = StoreWriter.open(out, _store_meta(cfg, desc), lock)
        run = {
            "command": shlex.join(sys.argv),
            "config": config_to_dict(cfg),
            "versions": versions(),
            "device": desc.model.get("device"),
            "started": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        }
        writer.update_meta(runs=[*writer.meta.get("runs", []), run])
        known = {(e.task, e.init): e.success for e in writer.outcomes().values() if e.attempt == 0}
        budget = min(cfg.max_tries_per_task or left, left)
        plan = Plan(tasks, cfg.episodes_per_task, budget, known, first=cfg.first_init)
        progress = _Progress(cfg, plan)
        result = CollectResult(out, {}, [])
        _loop(cfg, executor, writer, plan, progress, result)
        result.kept = {t: plan.kept(t) for t in tasks}
        result.exhausted = [t for t in tasks if plan.exhausted(t)]
        result.wall_seconds = time.perf_counter() - start
        run["finished"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
        run["episodes_added"] = len(result.published)
        writer.update_meta(runs=[*writer.meta["runs"][:-1], run])
    finally:
        if progress is not None:
            progress.close()
        executor.close()
        if writer is not None:
            writer.close()
    return result


def _loop(
    cfg: CollectConfig,
    executor: Executor,
    writer: StoreWriter,
    plan: Plan,
    progress: _Progress,
    result: CollectResult,
) -> None:
    """Launch, wait, write, decide, until every task's prefix is known."""
    speculate = executor.capacity > 1
    held: dict[Unit, tuple[EpisodeInfo, str, StagedEpisode | None]] = {}
    running = 0
    while not plan.complete():
        while (
            running < executor.capacity
            and (unit := plan.next_unit(speculate, executor.affinity())) is not None
        ):
            executor.submit(unit, unit_seed(cfg.policy.seed, unit))
            plan.started(unit)
            running += 1
        if running == 0:  # the plan's invariants exclude it
            raise RuntimeError("collection plan stalled with nothing running")
        finished = executor.wait()
        while finished:
            unit, episode = finished.pop(
                0
            )  # dropped after this pass: its buffers are freed before the next wait
            running -= 1
            result.episodes_run += 1
            result.steps += episode.info.length
            result.episode_seconds += episode.seconds
            result.label_seconds += episode.label_seconds
            result.simulators_built += episode.built
            result.build_seconds += episode.build_seconds
            t0 = time.perf_counter()
            staged = None
            if episode.info.success or cfg.keep_failed:
                staged = writer.stage(episode.info, episode.steps.arrays(), episode.attrs.to_json())
            held[unit] = (episode.info, episode.attrs.instruction, staged)
            for decided, keep in plan.finished(unit, episode.info.success):
                done, instruction, staged_done = held.pop(decided)
                if keep and staged_done is not None:
                    writer.publish(staged_done)
                    result.published.append(decided.key)
                elif keep:
                    writer.mark_failed(done, {"instruction": instruction})
                elif staged_done is not None:
                    writer.discard(staged_done)
            result.write_seconds += time.perf_counter() - t0
            progress.finished(episode)


def _report(cfg: CollectConfig, result: CollectResult) -> None:
    for task, (successes, tries) in sorted(result.kept.items()):
        note = f"; try budget ({tries} init states) exhausted" if task in result.exhausted else ""
        print(f"task {task}: {successes}/{cfg.episodes_per_task} successful episodes, {tries} tried{note}")
    overhead = result.label_seconds + result.write_seconds
    share = overhead / max(1e-9, result.episode_seconds + result.write_seconds)
    print(
        f"store {result.path}: added {len(result.published)} episode(s); this run: {result.episodes_run} episodes, "
        f"{result.steps} steps, {result.steps / max(1e-9, result.wall_seconds):.2f} steps/s, "
        f"labelling+writing {100 * share:.1f}% of step time; {result.simulators_built} simulator(s) built "
        f"({result.build_seconds:.0f} s)"
    )
