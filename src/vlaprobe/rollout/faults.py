"""Faults injected into the scripted expert (``--expert-faults SPEC``): natural failures from one driver.

A failure detector trained on expert successes and policy failures separates the drivers, not the outcomes.
Here the one expert driver both succeeds and fails: :class:`FaultSpec` gives each fault a probability per
episode (``noise`` a scale), :class:`FaultyExpert` draws from the episode's seed which faults an episode gets
and applies them to the expert's actions, and records where each hit (:class:`FaultMark`) and the row from
which the failure was certain (``failure_step``: the expert gave up, or let go on the wrong target).

- ``noise=S``: Gaussian noise of standard deviation S on the six motion components of every action (action
  units; the expert's are clipped to [-1, 1]); the expert re-plans from wherever it lands.
- ``release=P``: the gripper opens while the object is carried away from the target, and the expert gives up
  (holds still, fingers open): the failure is certain from that row.
- ``wrong_target=P``: the expert places the object on another low object of the table than the goal's.
- ``no_recovery=P``: the first time the expert would re-grasp (a slipped grasp, or a ``--perturb`` drop or
  displacement) it gives up instead.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, cast

import numpy as np

from vlaprobe.envs.base import TaskEnv
from vlaprobe.errors import VlaprobeError
from vlaprobe.rollout.perturb import parse_kinds
from vlaprobe.symbols import Goal, Scene, WorldState

KINDS = ("noise", "release", "wrong_target", "no_recovery")
"""Fault kinds, in the order their draws are made."""
GRIPPER_OPEN = -1.0
RELEASE_AFTER = (1, 6)
"""Range of rows held (lifting or carrying, away from the target) after which a release happens."""
RELEASE_AWAY = 0.10
"""Least horizontal distance (metres) of the carried object from the place target for a release."""
LOW_TARGET = 0.12
"""Greatest height (metres) of a wrong target's top above the table (a plate, a box, a ramekin; no cabinet)."""


@dataclass(frozen=True)
class FaultSpec:
    """Probability per episode of each fault (``noise``: the noise's standard deviation, every episode)."""

    noise: float = 0.0
    release: float = 0.0
    wrong_target: float = 0.0
    no_recovery: float = 0.0

    @classmethod
    def parse(cls, text: str, flag: str = "--expert-faults") -> FaultSpec:
        """``"kind=value,..."`` with kinds from :data:`KINDS`; probabilities in [0, 1], noise ≥ 0."""
        return cls(**parse_kinds(text, flag, "fault", KINDS, "noise=0.3,release=0.2", scales=("noise",)))

    @property
    def any(self) -> bool:
        return any(getattr(self, k) > 0 for k in KINDS)

    def text(self) -> str:
        return ",".join(f"{k}={getattr(self, k):g}" for k in KINDS if getattr(self, k) > 0)


@dataclass(frozen=True)
class FaultMark:
    """A fault that hit an episode."""

    kind: str
    """One of :data:`KINDS` (noise is not marked: it hits every row)."""
    row: int
    """The row whose action it changed first."""


class RetargetableExpert(Protocol):
    """What the faults need of the scripted expert: its action, its phase, and a settable place target."""

    phase: str

    def reset(self) -> None: ...

    def act(self) -> np.ndarray: ...

    def retarget(self, name: str) -> None: ...


@dataclass
class FaultyExpert:
    """The scripted expert with faults drawn from ``seed`` (a :class:`~vlaprobe.rollout.Driver`)."""

    expert: RetargetableExpert
    spec: FaultSpec
    seed: int
    scene: Scene
    goal: Goal
    world: Callable[[], WorldState]
    """The simulator's current state (where the carried object is)."""
    marks: list[FaultMark] = field(default_factory=list)
    failure_step: int | None = None
    """The row from which the failure was certain (the expert gave up or let go on a wrong target)."""

    def reset(self) -> None:
        self.expert.reset()
        draw = np.random.default_rng([self.seed, 4099])
        self._noise_rng = np.random.default_rng([self.seed, 4111])
        self._release = draw.random() < self.spec.release
        self._release_after = int(draw.integers(*RELEASE_AFTER))
        wrong = draw.random() < self.spec.wrong_target
        target = self._wrong_target(draw)
        self._no_recovery = draw.random() < self.spec.no_recovery
        self.marks, self.failure_step = [], None
        self._row, self._carried, self._gave_up = 0, 0, False
        self._wrong = wrong and target is not None
        if self._wrong:
            assert target is not None
            self.expert.retarget(target)
            self.marks.append(FaultMark("wrong_target", 0))

    def _wrong_target(self, rng: np.random.Generator) -> str | None:
        """A low tabletop object other than the goal's (drawn whether used or not: fixed draw order)."""
        world = self.world()
        names = self.scene.tabletop
        low = [
            n
            for i, n in enumerate(names)
            if n not in (self.goal.pick, self.goal.place)
            and world.aabb_hi[i, 2] - world.table_height < LOW_TARGET
        ]
        pick = int(rng.integers(len(low))) if low else 0
        return low[pick] if low else None

    def _give_up(self, kind: str) -> None:
        self._gave_up = True
        self.marks.append(FaultMark(kind, self._row))
        self.failure_step = self._row

    def act(self, obs: object = None, prediction: object = None) -> np.ndarray:
        action = np.asarray(self.expert.act(), dtype=np.float64).copy()
        phase = self.expert.phase
        if not self._gave_up:
            if self._no_recovery and phase == "regrasp":
                self._give_up("no_recovery")
            elif self._release and phase in ("lift", "carry") and self._away():
                self._carried += 1
                if self._carried > self._release_after:
                    self._give_up("release")
            elif self._wrong and phase == "release" and self.failure_step is None:
                self.failure_step = self._row
        if self._gave_up:
            action = np.zeros(7)
            action[6] = GRIPPER_OPEN
        elif self.spec.noise > 0:
            action[:6] += self._noise_rng.normal(0.0, self.spec.noise, 6)
        self._row += 1
        return action

    def _away(self) -> bool:
        world = self.world()
        i, j = self.scene.tabletop.index(self.goal.pick), self.scene.tabletop.index(self.goal.place)
        return bool(np.linalg.norm(world.pos[i, :2] - world.pos[j, :2]) > RELEASE_AWAY)

    def expert_label(self) -> np.ndarray | None:
        return None


def with_faults(driver: object, env: TaskEnv, spec: FaultSpec, seed: int) -> FaultyExpert:
    """The expert ``driver`` of one episode in ``env`` with the faults of ``spec`` (the expert driver only:
    the faults change the expert's own actions)."""
    from vlaprobe.rollout.drivers import ExpertDriver

    expert = getattr(driver, "expert", None)
    if not isinstance(driver, ExpertDriver) or not hasattr(expert, "retarget"):
        raise VlaprobeError(
            "--expert-faults changes the scripted expert's actions; use it with --driver expert"
        )
    return FaultyExpert(cast(RetargetableExpert, expert), spec, seed, env.scene, env.goal, env.world_state)
