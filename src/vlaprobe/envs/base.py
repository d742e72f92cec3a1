"""The environment interface the step loop sees (:class:`TaskEnv`, :class:`Observation`), implemented by
``LiberoTaskEnv``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from vlaprobe.symbols import Goal, Labeler, Scene, WorldState
from vlaprobe.symbols.goals import GoalConjunction

__all__ = ["Observation", "TaskEnv"]


@dataclass
class Observation:
    """What a policy sees after a reset or a step."""

    image: np.ndarray | None
    """Raw agentview render (H, W, 3) uint8 as robosuite returns it (upside down); None when not rendering."""
    proprio: np.ndarray
    """float32 (9,): end-effector position (3), quaternion xyzw (4), finger joint positions (2)."""
    step: int
    """Steps since the settled reset (0 at the first observation)."""
    success: bool
    """LIBERO's own goal check."""


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
    """The task's pick-and-place goal (LIBERO-spatial; absent where the goal is not one ``On`` between objects)."""
    goal_conjunction: GoalConjunction
    """The task's BDDL goal, every conjunct."""
    perturb_goal: Goal | None
    """The object ``--perturb`` drops, displaces or knocks off and where it goes
    (:func:`~vlaprobe.envs.bddl_scene.carried_object_goal`); None where the goal carries no one object."""
    robot_base: tuple[float, float]
    """(x, y) of the robot's base: a moved object lands within reach of it (``rollout.perturb.REACH``)."""
    labeler: Labeler
    """The ground-truth detectors of this scene: ``labeler(world_state) -> (object bits, action bits)``."""

    def reset(self, init: int) -> Observation: ...

    def step(self, action: np.ndarray) -> Observation: ...

    def world_state(self) -> WorldState: ...

    def drawer_fronts(self) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        """(x, y) low and high corners of the table area each drawer of the scene opens over, its handle's hand
        included (where ``--perturb`` lands nothing when the goal goes into a drawer)."""
        ...

    def place_object(self, name: str, xy: tuple[float, float]) -> Observation:
        """Move a movable object to (x, y), resting on the table, and observe again (a perturbation)."""
        ...

    def close(self) -> None: ...
