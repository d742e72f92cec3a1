"""Small stand-ins for LIBERO, the model and the expert, with the same interfaces, for fast collection tests.

The scene is a real :class:`~vlaprobe.symbols.Scene` (two pickupables, a cabinet with one drawer) labelled by
the real :class:`~vlaprobe.symbols.Labeler` on synthetic world states. Whether an episode succeeds depends
only on (task, init), like a deterministic expert: see :func:`succeeds`. ``FAKE_STEP_SECONDS`` in the
environment slows every step down (for the kill -9 test).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from functools import partial
from typing import Any, ClassVar

import numpy as np

from vlaprobe.collection.worker import Worker
from vlaprobe.envs.base import Observation
from vlaprobe.rollout import DaggerDriver, PolicyDriver
from vlaprobe.symbols import Articulation, Goal, Labeler, Scene, WorldState
from vlaprobe.symbols.goals import Conjunct, GoalConjunction

NUM_TASKS, NUM_INITS, LAYERS, HIDDEN, IMAGE = 3, 12, 4, 8, 16
SCENE = Scene(
    pickupable=("bowl", "plate"),
    fixtures=("cabinet",),
    containers=("cabinet_top",),
    container_articulation=(Articulation(threshold=-0.14, below=True),),
    region_parent={"cabinet_top": "cabinet"},
)
GOAL = Goal(pick="bowl", place="plate")
GOAL_CONJUNCTION = GoalConjunction((Conjunct("On", ("bowl", "plate")),))


def succeeds(task: int, init: int) -> bool:
    """The fixed outcome of a unit: about one in three fails."""
    return (3 * task + 5 * init) % 7 not in (1, 4)


def success_step(task: int, init: int) -> int:
    return 2 + (task + init) % 3


class FakeEnv:
    SCENES: ClassVar[dict[int, Scene]] = {}
    """Task -> its scene where it is not :data:`SCENE` (a test gives tasks different objects)."""

    def __init__(self, task: int, cfg: Any) -> None:
        self.task_index = task
        self.instruction = f"put the bowl on the plate ({task})"
        self.num_init_states = NUM_INITS
        self.scene, self.goal, self.goal_conjunction = self.SCENES.get(task, SCENE), GOAL, GOAL_CONJUNCTION
        self.perturb_goal = GOAL
        self.robot_base = (-0.66, 0.0)
        self.labeler = Labeler(self.scene, GOAL)
        self.delay = float(os.environ.get("FAKE_STEP_SECONDS", "0"))

    def drawer_fronts(self) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        return ((np.array([0.0, -0.3]), np.array([0.1, 0.0])),)

    def reset(self, init: int) -> Observation:
        self.init, self.t = init, 0
        self.moves: list[tuple[int, str, tuple[float, float]]] = []
        self.labeler.reset()
        return self._observe()

    def _observe(self) -> Observation:
        rng = np.random.default_rng([self.task_index, self.init, self.t])
        self.rng = rng
        image = rng.integers(0, 256, (IMAGE, IMAGE, 3), dtype=np.uint8)
        success = succeeds(self.task_index, self.init) and self.t >= success_step(self.task_index, self.init)
        return Observation(
            image=image, proprio=rng.random(9).astype(np.float32), step=self.t, success=success
        )

    def place_object(self, name: str, xy: tuple[float, float]) -> Observation:
        self.moves.append((self.t, name, xy))
        return self._observe()

    def step(self, action: np.ndarray) -> Observation:
        time.sleep(self.delay)
        self.t += 1
        return self._observe()

    def world_state(self) -> WorldState:
        rng = np.random.default_rng([self.task_index, self.init, self.t, 1])
        n, n_pick = len(self.scene.tabletop), len(self.scene.pickupable)  # 3 and 2 in SCENE
        pos = rng.uniform(-0.2, 0.2, (n, 3)) + np.array([0.0, 0.0, 0.9])
        contact = rng.random((n + 3, n + 3)) < 0.3  # the objects, the table, two fingers
        return WorldState(
            pos=pos,
            aabb_lo=pos - 0.03,
            aabb_hi=pos + 0.03,
            contact=contact | contact.T,
            region_pos=pos[n - 1 : n],
            region_mat=np.eye(3)[None],
            region_size=np.full((1, 3), 0.05),
            container_qpos=rng.uniform(-0.3, 0.0, 1),
            on_off_qpos=np.zeros(0),
            camera_pos=np.array([1.0, 0.0, 1.6]),
            camera_mat=np.array([[0.0, -0.5, 0.87], [1.0, 0.0, 0.0], [0.0, 0.87, 0.5]]),
            camera_fovy=45.0,
            eef_pos=rng.uniform(-0.2, 0.2, 3) + np.array([0.0, 0.0, 1.0]),
            gripper_qpos=rng.uniform(0.0, 0.04, 2),
            gripper_command=float(rng.choice([-1.0, 1.0])),
            table_height=0.9,
            # Drawn after the fields above, so that their values do not depend on these.
            gripper_qvel=np.zeros(2),
            lin_vel=np.zeros((n, 3)),
            ang_vel=np.zeros((n, 3)),
            finger_gap=np.where(
                (contact | contact.T)[:n_pick, n + 1 : n + 3], 0.0, 0.01
            ),  # the fingers' contacts
        )

    def close(self) -> None:
        pass


@dataclass
class FakeStep:
    action: np.ndarray
    hidden: np.ndarray
    model_image: np.ndarray
    action_tokens: np.ndarray


class FakePolicy:
    def __init__(self, cfg: Any, suite: str = "libero_spatial") -> None:  # a PolicyConfig and the suite
        self.model_id, self.pooling, self.seed = "fake", cfg.pooling, cfg.seed
        self.num_hidden_states, self.hidden_size = LAYERS, HIDDEN

    def step(self, image: np.ndarray, instruction: str) -> FakeStep:
        rng = np.random.default_rng([int(image.sum()), self.seed])
        shape = (LAYERS, 7, HIDDEN) if self.pooling == "action_tokens" else (LAYERS, HIDDEN)
        return FakeStep(
            action=rng.uniform(-1, 1, 7),
            hidden=rng.standard_normal(shape).astype(np.float32),
            model_image=image[::-1, ::-1].copy(),
            action_tokens=rng.integers(31744, 32000, 7),
        )

    def describe(self) -> dict[str, Any]:
        return {"model_id": "fake", "seed": self.seed, "device": "cpu", "pooling": self.pooling}


class FakeScriptedExpert:
    """The scripted expert's interface on the fake simulator: close the gripper after step 1."""

    def __init__(self, env: FakeEnv) -> None:
        self.env = env

    def reset(self) -> None:
        pass

    def act(self) -> np.ndarray:
        return np.array([0.1, 0.0, -0.1, 0.0, 0.0, 0.0, 1.0 if self.env.t > 1 else -1.0])


class FakeExpert:
    """The "expert" driver; the "policy" driver executes the fake model's own action."""

    def __init__(self, env: FakeEnv, seed: int) -> None:
        self.expert = FakeScriptedExpert(env)

    def reset(self) -> None:
        pass

    def act(self, obs: Observation, prediction: Any) -> np.ndarray:
        return self.expert.act()

    def expert_label(self) -> np.ndarray | None:
        return None


def fake_driver(name: str, env: Any, policy: Any, seed: int, beta: float = 0.0) -> Any:
    if name == "dagger":
        return DaggerDriver(FakeScriptedExpert(env), seed, beta)
    return FakeExpert(env, seed) if name == "expert" else PolicyDriver()


def fake_tasks(cfg: Any) -> dict[int, str]:
    return {t: f"put the bowl on the plate ({t})" for t in range(NUM_TASKS)}


def fake_scenes(cfg: Any, tasks: Any) -> list[Scene]:
    """The scenes of ``tasks`` (what the real worker reads from the BDDL files)."""
    return [FakeEnv.SCENES.get(t, SCENE) for t in tasks]


make_fake_worker = partial(
    Worker,
    make_env=FakeEnv,
    make_policy=FakePolicy,
    make_driver=fake_driver,
    list_tasks=fake_tasks,
    task_scenes=fake_scenes,
)
"""A picklable worker factory (spawned processes and Ray actors import this module to rebuild it)."""


def serial_keys(tasks: list[int], per_task: int, budget: int, keep_failed: bool) -> list[str]:
    """The episode keys the serial rule yields for the fake outcomes (the expected result of any run)."""
    keys = []
    for t in tasks:
        successes = 0
        for i in range(budget):
            if successes >= per_task:
                break
            ok = succeeds(t, i)
            successes += ok
            if ok or keep_failed:
                keys.append(f"t{t:02d}_i{i:02d}_a00")
    return keys


def fake_probed_run(root: Any, *, shuffled_control: bool = True) -> None:
    """``root/activations`` (12 fake episodes of tasks 0-2, the real writer) and ``root/probes`` trained on
    them with small bootstraps: the run folder the live and results tests start from."""
    from vlaprobe.collection.collect import collect
    from vlaprobe.configs.collect import CollectConfig
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.configs.train import TrainConfig
    from vlaprobe.probes.train import train_probes

    cfg = CollectConfig(
        out=root / "activations",
        tasks=(0, 1, 2),
        episodes_per_task=4,
        max_tries_per_task=12,
        progress=False,
        env=EnvConfig(max_steps=6, image_size=16),
    )
    collect(cfg, make_fake_worker)
    train_probes(
        TrainConfig(
            store=cfg.out,
            out=root / "probes",
            bootstrap=20,
            auprc_bootstrap=5,
            shuffled_control=shuffled_control,
        )
    )
