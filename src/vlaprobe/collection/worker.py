"""One collection worker: a model and a simulator in one process, running one episode at a time.

The worker runs the one step loop (:func:`vlaprobe.rollout.run_episode`) and buffers its records into the
per-step arrays of the store, so that the image, hidden states, labels, proprioception and both actions of a
row all belong to the same timestep (under the scripted expert the model observes the buffered images after
the episode, in batches: :class:`vlaprobe.rollout.DeferredObserver`). The episode is handed back whole; the
parent process writes it.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from vlaprobe.collection.defined import TaskColumns
from vlaprobe.collection.episode import (
    EpisodeAttrs,
    EpisodeSteps,
    PerturbationMark,
    PerturbationMiss,
    StepRows,
)
from vlaprobe.collection.plan import Unit
from vlaprobe.collection.store import EpisodeInfo
from vlaprobe.collection.takeovers import MakeSupervisor, matched_counts, random_supervisor
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.configs.env import EnvConfig, SuiteName
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.envs import make_env
from vlaprobe.envs.base import TaskEnv
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject
from vlaprobe.policies.base import BatchObserver, VLAPolicy
from vlaprobe.rollout import (
    DeferredObserver,
    EnvCache,
    EpisodeControl,
    EpisodeRunner,
    StepRecord,
    SuccessTracker,
    make_driver,
)
from vlaprobe.rollout.faults import FaultSpec, FaultyExpert
from vlaprobe.rollout.perturb import KIND_CODE, Perturber, PerturbSpec, episode_perturber
from vlaprobe.rollout.runner import MakeDriver, default_threads
from vlaprobe.rollout.takeover import Supervisor, TakeoverDriver
from vlaprobe.symbols import HEADS, Scene
from vlaprobe.symbols.vocabulary import atom


@dataclass
class EpisodeResult:
    """A finished episode, ready to be written."""

    info: EpisodeInfo
    steps: EpisodeSteps
    """The per-step columns."""
    attrs: EpisodeAttrs
    """Episode attributes besides :class:`EpisodeInfo` (instruction, scene, goal, placements, perturbations)."""
    seconds: float
    """Wall time of the step loop."""
    label_seconds: float
    """Of which: world-state snapshots and detectors."""
    built: bool = False
    """The worker built the task's simulator for this episode (it held another task's, or none)."""
    build_seconds: float = 0.0
    """Time that build took (0 without one)."""


@dataclass
class RunDescription:
    """What a worker knows before any episode: the observer model and the suite (the store's metadata)."""

    model: JsonObject
    """The policy's JSON description (``VLAPolicy.describe()``)."""
    model_id: str
    num_hidden_states: int
    hidden_size: int
    pooling: str
    atom_names: dict[str, list[str]]
    """Atom names per label head ("object", "action"), in column order."""
    tasks: dict[int, str]
    """Every task of the suite: index -> instruction."""
    num_init_states: int
    """Init states per task (of the first selected task)."""


def unit_seed(seed: int, unit: Unit) -> int:
    """The seed of one episode, derived from the run's seed and the unit alone (same on any worker)."""
    text = f"{seed}:{unit.task}:{unit.init}:{unit.attempt}".encode()
    return int.from_bytes(hashlib.sha256(text).digest()[:4], "little") & 0x7FFFFFFF


def _make_policy(cfg: PolicyConfig, suite: SuiteName) -> VLAPolicy:
    from vlaprobe.policies.factory import make_policy

    return make_policy(cfg, suite)


def _suite_tasks(cfg: EnvConfig) -> dict[int, str]:
    from vlaprobe.envs.libero import suite_tasks

    return dict(suite_tasks(cfg.suite))


def _task_scenes(cfg: EnvConfig, tasks: Sequence[int]) -> list[Scene]:
    from vlaprobe.envs.bddl_scene import task_scene

    return [task_scene(cfg.suite, t, cfg.assets) for t in tasks]


MakeEnv = Callable[[int, EnvConfig], TaskEnv]
MakePolicy = Callable[[PolicyConfig, SuiteName], VLAPolicy]
ListTasks = Callable[[EnvConfig], dict[int, str]]
TaskScenes = Callable[[EnvConfig, Sequence[int]], list[Scene]]


class Worker:
    """Runs episodes: one model for the worker's life, one simulator at a time (rebuilt when the task changes).

    The factories default to the real pieces (:func:`vlaprobe.envs.make_env`,
    :func:`vlaprobe.policies.make_policy`, :func:`vlaprobe.rollout.make_driver`, the tasks' BDDL scenes); tests
    pass small fakes with the same interfaces.

    The store's vocabulary is the union of the selected tasks' scenes' (``envs.suite_vocabulary``): a task's
    own where all agree (LIBERO-spatial, LIBERO-goal). Each episode's labels are widened to it, and an episode
    whose task leaves atoms undefined records them (``collection.defined``).
    """

    def __init__(
        self,
        cfg: CollectConfig,
        make_env: MakeEnv = make_env,
        make_policy: MakePolicy = _make_policy,
        make_driver: MakeDriver = make_driver,
        list_tasks: ListTasks = _suite_tasks,
        make_supervisor: MakeSupervisor | None = None,
        task_scenes: TaskScenes = _task_scenes,
    ) -> None:
        """``make_supervisor``: the cognition's alarm of an episode (``--takeover alarm`` needs it)."""
        self.cfg = cfg
        self._list_tasks, self._task_scenes = list_tasks, task_scenes
        mode = cfg.intervention.takeover
        if mode == "alarm" and make_supervisor is None:
            raise VlaprobeError(
                "--takeover alarm needs the cognition's alarm; run it through `vlaprobe collect`"
            )
        if mode == "random" and cfg.intervention.takeover_match is None:
            raise VlaprobeError("--takeover random needs --takeover-match STORE (the alarm run to match)")
        if mode == "random" and cfg.intervention.takeover_until == "subgoal" and make_supervisor is None:
            raise VlaprobeError(
                "--takeover-until subgoal hands back by the cognition; run it through `vlaprobe collect`"
            )
        self._make_supervisor = make_supervisor
        match = cfg.intervention.takeover_match
        import torch

        torch.set_num_threads(cfg.threads or default_threads(cfg.workers))
        self.policy = make_policy(cfg.policy, cfg.env.suite)
        self._counts = (
            matched_counts(match, cfg.env.suite, self.policy.model_id)
            if mode == "random" and match is not None
            else {}
        )
        envs = EnvCache(lambda task: make_env(task, cfg.env), on_new=self._check_vocabulary)
        # The expert does not read the model: it observes each episode afterwards, in batches.
        self._deferred = (
            DeferredObserver(self.policy)
            if cfg.driver == "expert" and isinstance(self.policy, BatchObserver)
            else None
        )
        self.runner = EpisodeRunner(self._deferred or self.policy, envs, make_driver)
        self._atoms: dict[str, list[str]] | None = None
        self._columns: dict[int, TaskColumns] = {}

    @property
    def env(self) -> TaskEnv | None:
        """The current task's simulator (None before the first episode and after :meth:`close`)."""
        return self.runner.envs.env

    def store_atoms(self) -> dict[str, list[str]]:
        """The store's atom names per head: the union vocabulary of the selected tasks (sorted) of the suite."""
        if self._atoms is None:
            from vlaprobe.envs.suite_vocabulary import union_vocabulary

            tasks = sorted(self.cfg.tasks or self._list_tasks(self.cfg.env))
            vocab = union_vocabulary(self._task_scenes(self.cfg.env, tasks))
            self._atoms = {h: list(vocab.atoms(h)) for h in HEADS}
        return self._atoms

    def _check_vocabulary(self, task: int, env: TaskEnv) -> None:
        """Place the task's atoms among the store's (a task atom outside the union is an error)."""
        labeler = env.labeler
        own = {h: labeler.vocabulary.atoms(h) for h in HEADS}
        self._columns[task] = TaskColumns.of(
            self.store_atoms(), own, {"action": labeler.undefined_action_atoms}
        )

    def _env_for(self, task: int) -> TaskEnv:
        return self.runner.envs.get(task)

    def describe(self) -> RunDescription:
        """The model's and the suite's description, from the first selected task's simulator."""
        tasks = self._list_tasks(self.cfg.env)
        first = self.cfg.tasks[0] if self.cfg.tasks else min(tasks)
        env = self._env_for(first)
        p = self.policy
        return RunDescription(
            model=p.describe(),
            model_id=p.model_id,
            num_hidden_states=int(p.num_hidden_states),
            hidden_size=int(p.hidden_size),
            pooling=str(p.pooling),
            atom_names=self.store_atoms(),
            tasks={int(k): str(v) for k, v in tasks.items()},
            num_init_states=int(env.num_init_states),
        )

    def run(self, unit: Unit, seed: int) -> EpisodeResult:
        """Run one episode from the unit's init state (see :func:`vlaprobe.rollout.run_episode`).

        Rows are the observations before each action. A successful episode ends ``post_success_steps`` rows
        after the first observation where the task succeeds (the terminal row, action NaN), a failed one
        after ``env.max_steps`` actions."""
        built = self.runner.envs.builds
        start = time.perf_counter()
        env = self._env_for(unit.task)
        build = self.runner.envs.builds > built
        build_seconds = time.perf_counter() - start if build else 0.0
        spec = PerturbSpec.parse(self.cfg.perturb)
        supervisor = self._supervisor(env, unit, seed)
        control = EpisodeControl() if spec.any or supervisor is not None else None
        perturber = episode_perturber(spec, seed, env, self.cfg.env.max_steps)
        records = self.runner.run(
            env,
            self.cfg.driver,
            init=unit.init,
            seed=seed,
            max_steps=self.cfg.env.max_steps,
            post_success_steps=self.cfg.post_success_steps,
            control=control,
            beta=self.cfg.dagger_beta,
            faults=FaultSpec.parse(self.cfg.expert_faults),
            takeover=self.cfg.intervention.takeover,
            takeover_steps=self.cfg.intervention.takeover_steps,
            takeover_until=self.cfg.intervention.takeover_until,
        )
        start = time.perf_counter()
        rows, track, done = StepRows(), _Outcome(env, perturber, control), []
        for r in records:
            track.add(r)  # perturbations come due while the episode runs
            done.append(r)
            if supervisor is not None and control is not None:
                if reason := supervisor.observe(r):
                    control.take_over(reason)
                if back := supervisor.hand_back():
                    control.hand_back(back)
        if self._deferred is not None:
            done = self._deferred.fill(done, env.instruction)
        for r in done:
            rows.add(r)
        seconds = time.perf_counter() - start
        info = EpisodeInfo(
            key=unit.key,
            task=unit.task,
            init=unit.init,
            attempt=unit.attempt,
            success=track.success,
            length=track.rows,
            seed=seed,
            driver=self.cfg.driver,
            success_step=track.success_step,
        )
        steps = rows.steps(track.codes if perturber is not None else None)
        columns = self._columns[unit.task]
        steps.object_atoms = columns.widen("object", steps.object_atoms)
        steps.action_atoms = columns.widen("action", steps.action_atoms)
        attrs = _episode_attrs(env, perturber, round(seconds, 3))
        attrs.extra.update(columns.attrs(self.store_atoms()))
        if isinstance(faulty := self.runner.driver, FaultyExpert):
            attrs.faults, attrs.failure_step = list(faulty.marks), faulty.failure_step
        if isinstance(taking := self.runner.driver, TakeoverDriver):
            attrs.takeovers = taking.log
        return EpisodeResult(info, steps, attrs, seconds, track.label_seconds, build, build_seconds)

    def _supervisor(self, env: TaskEnv, unit: Unit, seed: int) -> Supervisor | None:
        """Who asks for takeovers in this episode (None without ``--takeover``)."""
        cfg = self.cfg.intervention
        rows = (
            random_supervisor(self._counts, unit.task, unit.init, seed, cfg)
            if cfg.takeover == "random"
            else None
        )
        if (
            cfg.takeover == "none"
            or self._make_supervisor is None
            or (rows is not None and cfg.takeover_until == "steps")
        ):
            return rows  # the random control without the cognition (checked in __init__)
        return self._make_supervisor(env, cfg, self.policy.model_id, rows)

    def close(self) -> None:
        self.runner.close()


class _Outcome:
    """What the worker learns from an episode's records besides their columns: its success step, the
    perturbations (handed to ``control`` as they come due) and the time spent labelling."""

    def __init__(self, env: TaskEnv, perturber: Perturber | None, control: EpisodeControl | None) -> None:
        self.perturber, self.control = perturber, control
        goal = perturber.goal if perturber is not None else None  # its grasp: when a drop may come
        actions = env.labeler.vocabulary.action_atoms
        self.grasp_col = actions.index(atom("grasped", goal.pick)) if goal is not None else -1
        self.codes: list[int] = []
        self.tracker = SuccessTracker()
        self.pending = ""
        self.rows, self.label_seconds = 0, 0.0

    def add(self, r: StepRecord) -> None:
        self.rows += 1
        self.label_seconds += r.timings.label_ms / 1000.0 if r.timings is not None else 0.0
        self.tracker.add(r)  # the loop's own rule: a success lost after a perturbation is not the episode's
        move = KIND_CODE.get(self.pending, 0) if r.perturbation == "move" else 0
        self.codes.append(KIND_CODE["drop"] if r.perturbation == "drop" else move)
        if self.perturber is not None and self.control is not None and r.world is not None:
            grasped = bool(r.action_atoms[self.grasp_col])
            self.pending = (
                self.perturber.observe(r.t, r.world, grasped, r.success, self.control) or self.pending
            )

    @property
    def success_step(self) -> int | None:
        return self.tracker.step

    @property
    def success(self) -> bool:
        return self.tracker.step is not None


def _episode_attrs(env: TaskEnv, perturber: Perturber | None, seconds: float) -> EpisodeAttrs:
    """The episode's attributes; those of sampled placements and perturbations only where they happened (so
    fixed-init, unperturbed stores keep their attributes)."""
    goal = getattr(env, "goal", None)  # absent where the task's goal is not one On(a, b) between objects
    attrs = EpisodeAttrs(instruction=env.instruction, scene=env.scene, goal=goal, seconds=seconds)
    placement = getattr(env, "last_placement", None)
    if getattr(env, "sampled", False) and placement is not None:
        attrs.inits = getattr(getattr(env, "cfg", None), "inits", "sampled")
        attrs.placement_seed = placement.seed
        attrs.placement_draws = placement.draws
        attrs.rejected_samples = list(placement.rejected)
        if placement.regions:
            attrs.placement_regions = dict(placement.regions)
    if perturber is not None:
        attrs.perturbations = [
            PerturbationMark(p.kind, p.row) for p in perturber.planned if p.row is not None
        ]
        attrs.perturbations_missed = [
            PerturbationMiss(p.kind, p.missed_row, p.reason) for p in perturber.unapplied()
        ]
    return attrs
