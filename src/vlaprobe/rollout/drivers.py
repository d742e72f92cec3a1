"""Who acts in an episode: the privileged scripted expert, the observed policy itself, or both (DAgger).

A :class:`Driver` chooses the executed action from the current observation and the observer model's step
on it (so the policy driver costs no second forward pass). :func:`make_driver` builds one by name.

The DAgger driver (Ross et al., 2011) lets the policy act and has the scripted expert label every visited
state with its own action: a policy trained on expert demonstrations drifts into states the demonstrations
never show, and these labels teach it to recover from them. The expert re-plans from whatever state the
simulator is in (``vlaprobe.experts``), so its label is meaningful wherever the policy went.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from vlaprobe.configs.collect import DriverName
from vlaprobe.envs.base import Observation, TaskEnv
from vlaprobe.errors import VlaprobeError
from vlaprobe.policies.base import PolicyStep, VLAPolicy


class Driver(Protocol):
    """Chooses the action executed after each observation."""

    def reset(self) -> None:
        """Start an episode (called right after the environment's reset)."""
        ...

    def act(self, obs: Observation, prediction: PolicyStep) -> np.ndarray:
        """The (7,) action to execute; ``prediction`` is the observer model's step on ``obs``."""
        ...

    def expert_label(self) -> np.ndarray | None:
        """The expert's (7,) action for the observation last acted on, where an expert labels states another
        actor visits (DAgger); None where the executed action is the only one."""
        ...


class ExpertDriver:
    """The scripted expert acts (it reads the simulator); the model only observes."""

    def __init__(self, env: TaskEnv, seed: int) -> None:
        self.expert = _scripted_expert(env, seed)

    def reset(self) -> None:
        self.expert.reset()

    def act(self, obs: Observation, prediction: PolicyStep) -> np.ndarray:
        return self.expert.act()

    def expert_label(self) -> np.ndarray | None:
        return None


class PolicyDriver:
    """The observed model acts: its own predicted action is executed (the paper's setting)."""

    def reset(self) -> None:
        pass

    def act(self, obs: Observation, prediction: PolicyStep) -> np.ndarray:
        return prediction.action

    def expert_label(self) -> np.ndarray | None:
        return None


class Expert(Protocol):
    """What the DAgger driver needs of an expert: an action for the simulator's current state."""

    def reset(self) -> None: ...

    def act(self) -> np.ndarray: ...


class DaggerDriver:
    """The policy acts, the expert labels (DAgger): on each step the expert's action is executed with
    probability ``beta`` (DAgger's mixing share), the policy's otherwise; the expert's is always the label.

    The expert is asked every step, whoever acts, so that its phase machine follows the episode."""

    def __init__(self, expert: Expert, seed: int, beta: float) -> None:
        if not 0.0 <= beta <= 1.0:
            raise VlaprobeError(f"--dagger-beta must be between 0 and 1, got {beta}")
        self.expert, self.seed, self.beta = expert, seed, beta
        self._label: np.ndarray | None = None
        self.reset()

    def reset(self) -> None:
        self.expert.reset()
        self._rng = np.random.default_rng([self.seed, 31])
        self._label = None

    def act(self, obs: Observation, prediction: PolicyStep) -> np.ndarray:
        self._label = np.asarray(self.expert.act(), dtype=np.float64)
        return self._label if self._rng.random() < self.beta else prediction.action

    def expert_label(self) -> np.ndarray | None:
        return self._label


def _scripted_expert(env: TaskEnv, seed: int) -> Expert:
    from vlaprobe.envs.libero import LiberoTaskEnv
    from vlaprobe.experts import ScriptedExpert

    if not isinstance(env, LiberoTaskEnv):
        raise VlaprobeError("the scripted expert reads the LIBERO simulator; use --driver policy elsewhere")
    return ScriptedExpert(env, seed=seed)


def make_driver(name: DriverName, env: TaskEnv, policy: VLAPolicy, seed: int, beta: float = 0.0) -> Driver:
    """The driver called ``name`` for one episode in ``env`` (``seed`` varies the expert's trajectories and
    DAgger's draws; ``beta`` is the dagger driver's share of expert-executed steps)."""
    if name == "expert":
        return ExpertDriver(env, seed)
    if name == "policy":
        return PolicyDriver()
    if name == "dagger":
        return DaggerDriver(_scripted_expert(env, seed), seed, beta)
    raise VlaprobeError(f"unknown driver {name!r}; use 'expert', 'policy' or 'dagger'")
