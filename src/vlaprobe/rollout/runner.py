"""The one episode runner: a simulator cache, driver construction, seeding, the loop and its control.

The collection worker and the live simulator source run episodes through :class:`EpisodeRunner`; the replay
of a stored episode goes through :func:`paced`, the same pause and stop (:meth:`EpisodeControl.proceed`) the
loop obeys between steps.
"""

from __future__ import annotations

import os
import random
import sys
import time
from collections.abc import Callable, Iterable, Iterator

import numpy as np

from vlaprobe.configs.collect import DriverName
from vlaprobe.configs.takeover import TakeoverMode, TakeoverUntil
from vlaprobe.envs.base import TaskEnv
from vlaprobe.errors import VlaprobeError
from vlaprobe.policies.base import VLAPolicy
from vlaprobe.rollout.drivers import DaggerDriver, Driver, make_driver
from vlaprobe.rollout.faults import FaultSpec, with_faults
from vlaprobe.rollout.loop import EpisodeControl, StepRecord, run_episode
from vlaprobe.rollout.takeover import TakeoverDriver

MakeDriver = Callable[[DriverName, TaskEnv, VLAPolicy, int, float], Driver]
"""Builds a driver: (name, simulator, observed policy, episode seed, DAgger's beta)."""


def seed_everything(seed: int) -> None:
    """Seed Python's, numpy's and (if loaded) torch's global generators for one episode."""
    random.seed(seed)
    np.random.seed(seed)
    if "torch" in sys.modules:
        sys.modules["torch"].manual_seed(seed)


def default_threads(workers: int) -> int:
    """Torch threads per process running episodes (``workers`` of them): half of its share of the cores. The
    simulator and the software renderer run in the same process; with every core given to torch, its OpenMP
    threads spin while the simulator steps (measured on 2 busy cores: the tiny model's step took 2.2 s with 2
    threads, 0.25 s with 1)."""
    return max(1, (os.cpu_count() or 1) // (2 * workers))


class EnvCache:
    """One simulator at a time, rebuilt when the task changes (building one takes seconds)."""

    def __init__(
        self, make_env: Callable[[int], TaskEnv], on_new: Callable[[int, TaskEnv], None] | None = None
    ) -> None:
        """``on_new(task, env)`` runs once per simulator built (e.g. to check its vocabulary)."""
        self._make_env, self._on_new = make_env, on_new
        self.env: TaskEnv | None = None
        self.builds = 0
        """Simulators built so far."""

    def get(self, task: int) -> TaskEnv:
        """The simulator of ``task`` (the previous one is closed first when the task changes)."""
        if self.env is None or self.env.task_index != task:
            self.close()
            self.env = self._make_env(task)
            self.builds += 1
            if self._on_new is not None:
                self._on_new(task, self.env)
        return self.env

    def close(self) -> None:
        if self.env is not None:
            self.env.close()
            self.env = None


class EpisodeRunner:
    """Runs episodes of the observed ``policy`` in the cached simulators."""

    def __init__(self, policy: VLAPolicy, envs: EnvCache, make_driver: MakeDriver = make_driver) -> None:
        self.policy, self.envs, self._make_driver = policy, envs, make_driver
        self.driver: Driver | None = None
        """The driver of the latest episode (its fault marks, where ``faults`` were given)."""

    def run(
        self,
        env: TaskEnv,
        driver: DriverName,
        *,
        init: int,
        seed: int,
        max_steps: int,
        post_success_steps: int = 0,
        control: EpisodeControl | None = None,
        beta: float = 0.0,
        faults: FaultSpec | None = None,
        takeover: TakeoverMode = "none",
        takeover_steps: int = 0,
        takeover_until: TakeoverUntil = "steps",
    ) -> Iterator[StepRecord]:
        """Seed, build the driver and run one episode (see :func:`vlaprobe.rollout.run_episode`); ``beta`` is
        the dagger driver's share of expert-executed steps, ``faults`` those injected into the expert;
        ``takeover`` other than "none": the scripted expert acts whenever ``control`` asks, until it is asked to
        hand back or for ``takeover_steps`` actions (``takeover_until``; :mod:`vlaprobe.rollout.takeover`)."""
        seed_everything(seed)
        chosen = self._make_driver(driver, env, self.policy, seed, beta)
        if faults is not None and faults.any:
            chosen = with_faults(chosen, env, faults, seed)
        if takeover != "none":
            chosen = self._with_takeover(
                chosen, driver, env, seed, control, (takeover, takeover_steps, takeover_until)
            )
        self.driver = chosen
        yield from run_episode(
            env,
            self.policy,
            chosen,
            init=init,
            max_steps=max_steps,
            post_success_steps=post_success_steps,
            control=control,
        )

    def _with_takeover(
        self,
        chosen: Driver,
        name: DriverName,
        env: TaskEnv,
        seed: int,
        control: EpisodeControl | None,
        how: tuple[TakeoverMode, int, TakeoverUntil],
    ) -> TakeoverDriver:
        if name == "expert":
            raise VlaprobeError(
                "--takeover hands the policy's control to the expert; use --driver policy or dagger"
            )
        if control is None:
            raise VlaprobeError("a takeover is asked for through the episode's control; pass one")
        # Under DAgger the driver's own expert labels every step: its label is the expert's action.
        expert = (
            None
            if isinstance(chosen, DaggerDriver)
            else self._make_driver("expert", env, self.policy, seed, 0.0)
        )
        return TakeoverDriver(chosen, expert, control, how[1], how[0], how[2])

    def close(self) -> None:
        self.envs.close()


def paced(
    records: Iterable[StepRecord], control: EpisodeControl | None = None, hz: float | None = None
) -> Iterator[StepRecord]:
    """Records of an episode already run (a stored one), at ``hz`` per second (None: as fast as they come),
    obeying ``control`` before each one as the loop does between steps."""
    next_at = time.monotonic()
    for rec in records:
        if control is not None and not control.proceed():
            return
        if hz:
            if not _sleep_until(next_at, control):
                return  # stopped while waiting
            next_at = max(next_at + 1.0 / hz, time.monotonic() - 1.0)
        yield rec


def _sleep_until(when: float, control: EpisodeControl | None) -> bool:
    """Wait until ``when`` (monotonic), waking every 50 ms to see a stop; False if stopped."""
    while (left := when - time.monotonic()) > 0:
        if control is not None and control.stopped:
            return False
        time.sleep(min(left, 0.05))
    return control is None or not control.stopped
