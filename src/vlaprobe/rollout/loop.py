"""The one step loop both collection and the live server run.

Per step ``t``: snapshot the world and label it (``label_ms``), show the observation to the observer model
(``model_ms``), let the driver choose the action (``driver_ms``), yield a :class:`StepRecord`, then step the
simulator (``env_ms``, reported on the next record). The image, hidden states, atoms, proprioception and both
actions of a record all belong to observation ``t``.

A caller may stop, pause or perturb the episode between steps through an :class:`EpisodeControl`;
collection passes none and buffers the records into the store (``vlaprobe.collection.worker``).
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from vlaprobe.envs.base import Observation, TaskEnv
from vlaprobe.errors import VlaprobeError
from vlaprobe.policies.base import PolicyStep, VLAPolicy
from vlaprobe.rollout.drivers import Driver
from vlaprobe.rollout.takeover import Takeover, TakeoverDriver
from vlaprobe.symbols import WorldState

GRIPPER_OPEN = -1.0


@dataclass
class StepTimings:
    """Where one step's time went, in milliseconds."""

    env_ms: float
    """The simulator step (with its camera render) that produced this observation; the reset for row 0."""
    label_ms: float
    """World-state snapshot and every detector."""
    model_ms: float
    """The observer model's step (preprocessing, forward pass with capture, action decoding); only the
    preprocessing when the model observes the episode afterwards (:class:`vlaprobe.rollout.DeferredObserver`)."""
    driver_ms: float
    """The driver's action choice (the scripted expert's planning; ~0 when the model drives)."""
    total_ms: float
    """All of the above."""


@dataclass
class StepRecord:
    """Everything known about one observation of an episode."""

    t: int
    """Row index in the episode (0 at the first observation)."""
    step: int
    """The simulator's step counter since the settled reset."""
    raw_image: np.ndarray | None
    """The agentview render as robosuite gives it (H, W, 3) uint8, upside down; None from a store."""
    model_image: np.ndarray
    """(224, 224, 3) uint8, upright: the image exactly as the model saw it."""
    hidden: np.ndarray
    """float32 (layers, hidden) or (layers, 7, hidden) for "action_tokens" pooling."""
    object_atoms: np.ndarray
    """bool, the vocabulary's object atoms in order."""
    action_atoms: np.ndarray
    """bool, the vocabulary's action atoms in order."""
    world: WorldState | None
    """The simulator snapshot the atoms were computed from; None from a store (which keeps it as columns)."""
    proprio: np.ndarray | None
    """float32 (9,): end-effector position, quaternion xyzw, finger joint positions; None if not stored."""
    action: np.ndarray
    """(7,) the action executed after this observation; NaN on the terminal row (none was executed)."""
    predicted_action: np.ndarray
    """(7,) the observer model's own action for this observation."""
    action_tokens: np.ndarray | None
    """(7,) the token ids the predicted action was decoded from; None if not stored."""
    success: bool
    """The task's own success check holds at this observation."""
    terminal: bool
    """The last row of the episode."""
    perturbed: bool
    """A perturbation changed this row: a drop (:meth:`EpisodeControl.drop`) overrode the driver's action, or a
    move (:meth:`EpisodeControl.move`) displaced an object just before this observation."""
    perturbation: str
    """Which: "drop", "move", or "" (none)."""
    timings: StepTimings | None
    """Where this step's time went; None from a store."""
    expert_action: np.ndarray | None = None
    """(7,) the scripted expert's action for this observation where it labels states the policy visits
    (``--driver dagger``; NaN on the terminal row); None under the other drivers."""
    takeover: Takeover | None = None
    """The takeover under which the scripted expert executed this row's action (``--takeover``); None when
    the driver acted, and in a store (which keeps an episode's takeovers as an attribute)."""


@dataclass
class SuccessTracker:
    """The episode's success, one rule for the loop, the collection worker and the live server.

    ``step`` is the onset of the success that counts: the first observation where the task's own check holds;
    once the episode has been perturbed (a drop or a move), a success that is lost again (an object knocked
    off its target) no longer counts, and a new onset does. Feed it every observation in order: a move is
    applied before its observation is judged, a drop after (it changes the action that follows).
    """

    step: int | None = None
    """Onset of the success that counts; None while there is none."""
    perturbed: bool = False
    """The episode has been perturbed."""

    def observe(self, t: int, success: bool) -> None:
        if success and self.step is None:
            self.step = t
        elif not success and self.perturbed:
            self.step = None

    def add(self, record: StepRecord) -> None:
        """Follow a recorded episode (live or stored) row by row."""
        if record.perturbation == "move":
            self.perturbed = True
        self.observe(record.t, record.success)
        if record.perturbation == "drop":
            self.perturbed = True


class EpisodeControl:
    """Stop, pause or perturb a running episode from another thread; the loop checks it between steps."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._running = threading.Event()
        self._running.set()
        self._drop_steps = 0
        self._move: tuple[str, tuple[float, float]] | None = None
        self._takeover: str | None = None
        self._hand_back: str | None = None
        self._success_hold = 0

    def stop(self) -> None:
        """End the episode after the current step (a paused loop wakes up and ends)."""
        self._stop.set()
        self._running.set()

    def pause(self) -> None:
        """Block the loop before its next simulator step until :meth:`resume` or :meth:`stop`."""
        self._running.clear()

    def resume(self) -> None:
        self._running.set()

    def drop(self, steps: int = 8) -> None:
        """Force the executed gripper command open (-1) for the next ``steps`` steps; then the driver goes on."""
        if steps < 1:
            raise VlaprobeError(f"drop needs at least 1 step, got {steps}")
        with self._lock:
            self._drop_steps = steps

    def move(self, name: str, xy: tuple[float, float] | np.ndarray) -> None:
        """Move object ``name`` to (x, y) on the table before the next observation (the driver re-plans)."""
        with self._lock:
            self._move = (name, (float(xy[0]), float(xy[1])))

    def hold_success(self, rows: int) -> None:
        """Keep a successful episode going for at least ``rows`` rows after its success onset (0: no hold; the
        episode's ``post_success_steps`` still apply): a perturbation due after the success (a knock-off, which
        waits for the release) must come before the episode ends."""
        if rows < 0:
            raise VlaprobeError(f"hold_success needs 0 or more rows, got {rows}")
        with self._lock:
            self._success_hold = rows

    @property
    def success_hold(self) -> int:
        """Rows after the success onset the episode is held open for (:meth:`hold_success`)."""
        return self._success_hold

    def take_over(self, reason: str) -> None:
        """Hand the next actions to the scripted expert (``--takeover``; ``reason`` is recorded with it)."""
        with self._lock:
            self._takeover = reason

    def take_takeover(self) -> str | None:
        """The reason of a pending takeover request, if any (consumes it)."""
        with self._lock:
            reason, self._takeover = self._takeover, None
            return reason

    def hand_back(self, reason: str) -> None:
        """End the running takeover: the policy acts from the next action on (``--takeover-until subgoal``)."""
        with self._lock:
            self._hand_back = reason

    def take_hand_back(self) -> str | None:
        """The reason of a pending hand-back request, if any (consumes it)."""
        with self._lock:
            reason, self._hand_back = self._hand_back, None
            return reason

    def take_move(self) -> tuple[str, tuple[float, float]] | None:
        """The pending move, if any (consumes it)."""
        with self._lock:
            move, self._move = self._move, None
            return move

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    @property
    def drop_left(self) -> int:
        """Steps of a requested drop not yet applied."""
        return self._drop_steps

    @property
    def paused(self) -> bool:
        return not self._running.is_set()

    def wait_while_paused(self) -> None:
        """Block while paused (returns at once when running or stopped)."""
        self._running.wait()

    def proceed(self) -> bool:
        """Between two steps: wait while paused; whether the episode goes on (False once stopped)."""
        self._running.wait()
        return not self._stop.is_set()

    def take_drop(self) -> bool:
        """Whether this step is perturbed (consumes one step of a pending drop)."""
        with self._lock:
            if self._drop_steps <= 0:
                return False
            self._drop_steps -= 1
            return True


def _ms(start: float) -> float:
    return (time.perf_counter() - start) * 1000.0


def _record(
    t: int,
    obs: Observation,
    out: PolicyStep,
    world: WorldState,
    atoms: tuple[np.ndarray, np.ndarray],
    action: np.ndarray,
    terminal: bool,
    perturbation: str,
    timings: StepTimings,
    expert_action: np.ndarray | None,
    takeover: Takeover | None,
) -> StepRecord:
    return StepRecord(
        t=t,
        step=obs.step,
        raw_image=obs.image,
        model_image=out.model_image,
        hidden=out.hidden,
        object_atoms=atoms[0],
        action_atoms=atoms[1],
        world=world,
        proprio=obs.proprio,
        action=action,
        predicted_action=out.action,
        action_tokens=out.action_tokens,
        success=obs.success,
        terminal=terminal,
        perturbed=bool(perturbation),
        perturbation=perturbation,
        timings=timings,
        expert_action=expert_action,
        takeover=takeover,
    )


def run_episode(
    env: TaskEnv,
    policy: VLAPolicy,
    driver: Driver,
    *,
    init: int,
    max_steps: int,
    post_success_steps: int = 0,
    control: EpisodeControl | None = None,
) -> Iterator[StepRecord]:
    """Reset ``env`` to init state ``init`` and yield one record per observation until the episode ends.

    The episode ends ``post_success_steps`` rows after the first observation where the task succeeds (that
    row is the terminal one, its action NaN), after ``max_steps`` actions without success (the observation
    after the last action is not recorded: nothing was learned from it and no action follows), or when
    ``control`` is stopped (then no further row is yielded; the last one yielded is not marked terminal).
    With ``post_success_steps == 0`` the success observation is the last row: it is the first state in which
    the goal atom holds. ``control`` may hold a success open longer (:meth:`EpisodeControl.hold_success`: a
    knock-off still to come). Once ``control`` has perturbed the episode, a success that is lost again (an object
    knocked off its target) no longer counts: the episode goes on until the task succeeds anew.
    """
    if max_steps < 1:
        raise VlaprobeError(f"--env.max-steps must be at least 1, got {max_steps}")
    if post_success_steps < 0:
        raise VlaprobeError(f"--post-success-steps must be 0 or more, got {post_success_steps}")
    start = time.perf_counter()
    obs: Observation = env.reset(init)
    driver.reset()
    env_ms = _ms(start)
    if obs.image is None:
        raise VlaprobeError("the simulator renders no image; the model needs it (drop --env.no-render)")
    success = SuccessTracker()
    for t in range(max_steps + 1):
        move = control.take_move() if control is not None else None
        if move is not None:
            obs = env.place_object(*move)
            success.perturbed = True
        success.observe(t, obs.success)
        after = post_success_steps if control is None else max(post_success_steps, control.success_hold)
        reached = success.step is not None and t >= success.step + after
        terminal = reached or t == max_steps
        if terminal and success.step is None:
            break
        t0 = time.perf_counter()
        world = env.world_state()
        object_atoms, action_atoms = env.labeler(world)
        t1 = time.perf_counter()
        assert obs.image is not None  # rendering is on (checked after the reset)
        out = policy.step(obs.image, env.instruction)
        t2 = time.perf_counter()
        perturbation = "move" if move is not None else ""
        action: np.ndarray
        label: np.ndarray | None  # the expert's action where it labels a step another actor took (DAgger)
        if terminal:
            action = np.full(7, np.nan)
            label = None if driver.expert_label() is None else np.full(7, np.nan)
        else:
            action = np.asarray(driver.act(obs, out), dtype=np.float64)
            label = driver.expert_label()
            if control is not None and control.take_drop():
                action = action.copy()
                action[6] = GRIPPER_OPEN
                perturbation, success.perturbed = "drop", True
        t3 = time.perf_counter()
        timings = StepTimings(
            env_ms=env_ms,
            label_ms=(t1 - t0) * 1e3,
            model_ms=(t2 - t1) * 1e3,
            driver_ms=(t3 - t2) * 1e3,
            total_ms=env_ms + (t3 - t0) * 1e3,
        )
        acting = driver.acting if isinstance(driver, TakeoverDriver) and not terminal else None
        acting = None if acting is None else dataclasses.replace(acting)  # as of this row
        yield _record(
            t,
            obs,
            out,
            world,
            (object_atoms, action_atoms),
            action,
            terminal,
            perturbation,
            timings,
            label,
            acting,
        )
        if terminal:
            return
        if control is not None and not control.proceed():
            return
        t4 = time.perf_counter()
        obs = env.step(action)
        env_ms = _ms(t4)
