"""Who acts in an episode: the privileged scripted expert, or the observed policy itself.

A :class:`Driver` chooses the executed action from the current observation and the observer model's step
on it (so the policy driver costs no second forward pass). :func:`make_driver` builds one by name.
"""

from __future__ import annotations

from typing import Literal, Protocol

import numpy as np

from vlaprobe.envs.base import Observation, TaskEnv
from vlaprobe.errors import VlaprobeError
from vlaprobe.policies.base import PolicyStep, VLAPolicy

DriverName = Literal["expert", "policy"]


class Driver(Protocol):
    """Chooses the action executed after each observation."""

    def reset(self) -> None:
        """Start an episode (called right after the environment's reset)."""
        ...

    def act(self, obs: Observation, prediction: PolicyStep) -> np.ndarray:
        """The (7,) action to execute; ``prediction`` is the observer model's step on ``obs``."""
        ...


class ExpertDriver:
    """The scripted expert acts (it reads the simulator); the model only observes."""

    def __init__(self, env: TaskEnv, seed: int) -> None:
        from vlaprobe.envs.libero import LiberoTaskEnv
        from vlaprobe.envs.libero_expert import ScriptedExpert

        if not isinstance(env, LiberoTaskEnv):
            raise VlaprobeError(
                "the scripted expert reads the LIBERO simulator; use --driver policy elsewhere"
            )
        self.expert = ScriptedExpert(env, seed=seed)

    def reset(self) -> None:
        self.expert.reset()

    def act(self, obs: Observation, prediction: PolicyStep) -> np.ndarray:
        return self.expert.act()


class PolicyDriver:
    """The observed model acts: its own predicted action is executed (the paper's setting)."""

    def reset(self) -> None:
        pass

    def act(self, obs: Observation, prediction: PolicyStep) -> np.ndarray:
        return prediction.action


def make_driver(name: DriverName, env: TaskEnv, policy: VLAPolicy, seed: int) -> Driver:
    """The driver called ``name`` for one episode in ``env`` (``seed`` varies the expert's trajectories)."""
    if name == "expert":
        return ExpertDriver(env, seed)
    if name == "policy":
        return PolicyDriver()
    raise VlaprobeError(f"unknown driver {name!r}; use 'expert' or 'policy'")
