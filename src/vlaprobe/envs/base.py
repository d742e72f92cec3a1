"""The environment interface the step loop sees (:class:`TaskEnv`), implemented by ``LiberoTaskEnv``."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from vlaprobe.envs.libero import Observation
from vlaprobe.symbols import Goal, Labeler, Scene, WorldState

__all__ = ["Observation", "TaskEnv"]


class TaskEnv(Protocol):
    """One task of a suite: reset to a fixed init state, step with a 7-D action, snapshot and label the world."""

    task_index: int
    """Index of the task in its suite."""
    instruction: str
    """The task's language instruction."""
    num_init_states: int
    """How many fixed init states the task has."""
    scene: Scene
    """The typed objects of the task."""
    goal: Goal
    """The task's pick-and-place goal."""
    labeler: Labeler
    """The ground-truth detectors of this scene: ``labeler(world_state) -> (object bits, action bits)``."""

    def reset(self, init: int) -> Observation: ...

    def step(self, action: np.ndarray) -> Observation: ...

    def world_state(self) -> WorldState: ...

    def place_object(self, name: str, xy: tuple[float, float]) -> Observation:
        """Move a movable object to (x, y), resting on the table, and observe again (a perturbation)."""
        ...

    def close(self) -> None: ...
