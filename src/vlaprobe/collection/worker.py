"""One collection worker: a model and a simulator in one process, running one episode at a time.

The worker runs the one step loop (:func:`vlaprobe.rollout.run_episode`) and buffers its records into the
per-step arrays of the store, so that the image, hidden states, labels, proprioception and both actions of a
row all belong to the same timestep. The episode is handed back whole; the parent process writes it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import random
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from vlaprobe.collection.plan import Unit
from vlaprobe.collection.store import EpisodeInfo
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.envs import make_env
from vlaprobe.envs.base import TaskEnv
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import Json, JsonObject
from vlaprobe.policies.base import VLAPolicy
from vlaprobe.rollout import Driver, DriverName, EpisodeControl, make_driver, run_episode
from vlaprobe.rollout.perturb import KIND_CODE, Perturber, PerturbSpec
from vlaprobe.symbols.vocabulary import atom

if TYPE_CHECKING:
    from vlaprobe.symbols import Goal, Scene, WorldState


@dataclass
class EpisodeResult:
    """A finished episode, ready to be written."""

    info: EpisodeInfo
    arrays: dict[str, np.ndarray]
    """Per-step arrays by store name (``hidden``, ``object_atoms``, ``image``, ``world/pos`` ...)."""
    attrs: JsonObject
    """Episode attributes besides :class:`EpisodeInfo` (instruction, scene, goal)."""
    seconds: float
    """Wall time of the step loop."""
    label_seconds: float
    """Of which: world-state snapshots and detectors."""


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


def _make_policy(cfg: PolicyConfig) -> VLAPolicy:
    from vlaprobe.policies.factory import make_policy

    return make_policy(cfg)


def _suite_tasks(cfg: EnvConfig) -> dict[int, str]:
    from vlaprobe.envs.libero import suite_tasks

    return dict(suite_tasks(cfg.suite))


def default_threads(workers: int) -> int:
    """Torch threads per worker: half of its share of the cores. The simulator and the software renderer run
    in the same process; with every core given to torch, its OpenMP threads spin while the simulator steps
    (measured on 2 busy cores: the tiny model's step took 2.2 s with 2 threads, 0.25 s with 1)."""
    return max(1, (os.cpu_count() or 1) // (2 * workers))


def _seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    if "torch" in sys.modules:
        sys.modules["torch"].manual_seed(seed)


MakeEnv = Callable[[int, EnvConfig], TaskEnv]
MakePolicy = Callable[[PolicyConfig], VLAPolicy]
MakeDriver = Callable[[DriverName, TaskEnv, VLAPolicy, int], Driver]
ListTasks = Callable[[EnvConfig], dict[int, str]]


class Worker:
    """Runs episodes: one model for the worker's life, one simulator at a time (rebuilt when the task changes).

    The factories default to the real pieces (:func:`vlaprobe.envs.make_env`,
    :func:`vlaprobe.policies.make_policy`, :func:`vlaprobe.rollout.make_driver`); tests pass small fakes with
    the same interfaces.
    """

    def __init__(
        self,
        cfg: CollectConfig,
        make_env: MakeEnv = make_env,
        make_policy: MakePolicy = _make_policy,
        make_driver: MakeDriver = make_driver,
        list_tasks: ListTasks = _suite_tasks,
    ) -> None:
        self.cfg = cfg
        self._make_env, self._make_driver, self._list_tasks = make_env, make_driver, list_tasks
        import torch

        torch.set_num_threads(cfg.threads or default_threads(cfg.workers))
        self.policy = make_policy(cfg.policy)
        self.env: TaskEnv | None = None
        self._atoms: tuple[tuple[str, ...], tuple[str, ...]] = ((), ())
        self._first_task = -1

    def _env_for(self, task: int) -> TaskEnv:
        if self.env is None or self.env.task_index != task:
            if self.env is not None:
                self.env.close()
                self.env = None
            self.env = self._make_env(task, self.cfg.env)
            vocab = self.env.labeler.vocabulary
            atoms = (tuple(vocab.object_atoms), tuple(vocab.action_atoms))
            if self._first_task >= 0 and atoms != self._atoms:
                raise VlaprobeError(
                    f"task {task} has another atom vocabulary than task {self._first_task}; "
                    "collect tasks with different scenes into separate stores (--tasks, --out)"
                )
            if self._first_task < 0:
                self._atoms, self._first_task = atoms, task
        return self.env

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
            atom_names={"object": list(self._atoms[0]), "action": list(self._atoms[1])},
            tasks={int(k): str(v) for k, v in tasks.items()},
            num_init_states=int(env.num_init_states),
        )

    def run(self, unit: Unit, seed: int) -> EpisodeResult:
        """Run one episode from the unit's init state (see :func:`vlaprobe.rollout.run_episode`).

        Rows are the observations before each action. A successful episode ends ``post_success_steps`` rows
        after the first observation where the task succeeds (the terminal row, action NaN), a failed one
        after ``env.max_steps`` actions."""
        env = self._env_for(unit.task)
        _seed_everything(seed)
        driver = self._make_driver(self.cfg.driver, env, self.policy, seed)
        rows: dict[str, list[Any]] = {k: [] for k in _STEP_ARRAYS}
        world: list[WorldState] = []
        label_s = 0.0
        success_step: int | None = None
        spec = PerturbSpec.parse(self.cfg.perturb)
        control = EpisodeControl() if spec.any else None
        perturber = Perturber(spec, seed, env.scene, env.goal) if spec.any else None
        grasp_col = env.labeler.vocabulary.action_atoms.index(atom("grasped", env.goal.pick))
        codes: list[int] = []
        pending, was_success, perturbed = "", False, False
        start = time.perf_counter()
        for r in run_episode(
            env,
            self.policy,
            driver,
            init=unit.init,
            max_steps=self.cfg.env.max_steps,
            post_success_steps=self.cfg.post_success_steps,
            control=control,
        ):
            label_s += r.timings.label_ms / 1000.0
            # A success lost after a perturbation (knocked off) is not the episode's: the last onset counts.
            if r.success and (success_step is None or (perturbed and not was_success)):
                success_step = r.t
            was_success = r.success
            move = KIND_CODE.get(pending, 0) if r.perturbation == "move" else 0
            codes.append(KIND_CODE["drop"] if r.perturbation == "drop" else move)
            perturbed |= r.perturbed
            for name, value in _row_values(r).items():
                rows[name].append(value)
            world.append(r.world)
            if perturber is not None and control is not None:
                pending = (
                    perturber.observe(r.t, r.world, bool(r.action_atoms[grasp_col]), r.success, control)
                    or pending
                )
        seconds = time.perf_counter() - start
        arrays = {name: np.asarray(np.stack(rows[name]), dtype=dtype) for name, dtype in _STEP_ARRAYS.items()}
        arrays["hidden"] = np.ascontiguousarray(np.moveaxis(arrays["hidden"], 0, 1))  # (layers, T, ...)
        arrays.update(world_arrays(world))
        if perturber is not None:
            arrays["perturbation"] = np.asarray(codes, dtype=np.int8)
        info = EpisodeInfo(
            key=unit.key,
            task=unit.task,
            init=unit.init,
            attempt=unit.attempt,
            success=success_step is not None and (not perturbed or was_success),
            length=len(world),
            seed=seed,
            driver=self.cfg.driver,
            success_step=success_step,
        )
        attrs = {
            "instruction": env.instruction,
            "scene": dataclasses.asdict(env.scene),
            "goal": dataclasses.asdict(env.goal),
            "seconds": round(seconds, 3),
            **_episode_marks(env, perturber),
        }
        return EpisodeResult(info, arrays, attrs, seconds, label_s)

    def close(self) -> None:
        if self.env is not None:
            self.env.close()
            self.env = None


def _row_values(r: Any) -> JsonObject:
    """One record's values of the per-step arrays."""
    return {
        "hidden": np.asarray(r.hidden, dtype=np.float16),
        "object_atoms": r.object_atoms,
        "action_atoms": r.action_atoms,
        "image": r.model_image,
        "proprio": r.proprio,
        "action": r.action,
        "predicted_action": r.predicted_action,
        "action_tokens": r.action_tokens,
        "step": r.step,
    }


def _episode_marks(env: TaskEnv, perturber: Perturber | None) -> JsonObject:
    """Episode attributes of sampled placements and perturbations (none under the defaults, so fixed-init,
    unperturbed stores keep their attributes)."""
    marks: JsonObject = {}
    placement = getattr(env, "last_placement", None)
    if getattr(env, "sampled", False) and placement is not None:
        marks["inits"] = "sampled"
        marks["placement_seed"] = placement.seed
        marks["placement_draws"] = placement.draws
        marks["rejected_samples"] = list(placement.rejected)
    if perturber is not None:
        marks["perturbations"] = [
            {"kind": p.kind, "row": p.row} for p in perturber.planned if p.row is not None
        ]
    return marks


_STEP_ARRAYS: JsonObject = {
    "hidden": np.float16,
    "object_atoms": bool,
    "action_atoms": bool,
    "image": np.uint8,
    "proprio": np.float32,
    "action": np.float32,
    "predicted_action": np.float32,
    "action_tokens": np.int32,
    "step": np.int32,
}
"""The per-step arrays of an episode and their stored dtypes (besides ``world/*``)."""


def world_arrays(states: list[WorldState]) -> dict[str, np.ndarray]:
    """Stack per-step :class:`~vlaprobe.symbols.WorldState` snapshots into ``world/<field>`` arrays (steps first)."""
    fields = [f.name for f in dataclasses.fields(states[0])]
    return {f"world/{name}": np.stack([np.asarray(getattr(s, name)) for s in states]) for name in fields}


def world_states(arrays: Mapping[str, np.ndarray]) -> list[WorldState]:
    """The per-step :class:`~vlaprobe.symbols.WorldState` snapshots stored with an episode."""
    from vlaprobe.symbols import WorldState

    columns = {f.name: arrays[f"world/{f.name}"] for f in dataclasses.fields(WorldState)}
    length = len(next(iter(columns.values())))
    # A (steps,) column holds a scalar field (fovy, gripper command); array fields are at least (steps, k).
    return [
        WorldState(**{name: float(c[t]) if c.ndim == 1 else c[t] for name, c in columns.items()})
        for t in range(length)
    ]


def stored_scene(attrs: Mapping[str, Json]) -> tuple[Scene, Goal]:
    """(Scene, Goal) of an episode from its attributes, to rebuild its :class:`~vlaprobe.symbols.Labeler`."""
    from vlaprobe.symbols import Articulation, Goal, Scene

    kwargs: JsonObject = {}
    for f in dataclasses.fields(Scene):
        value = attrs["scene"][f.name]
        if f.name.endswith("articulation"):
            value = tuple(Articulation(**a) for a in value)
        kwargs[f.name] = tuple(value) if isinstance(value, list) else value
    return Scene(**kwargs), Goal(**attrs["goal"])
