"""What every skill of the scripted expert shares: privileged reads of the simulator and the arm's controller.

Actions follow robosuite's OSC_POSE controller as LIBERO configures it (``osc_pose.json``): each step sets the
goal pose relative to the current end-effector pose; position offset = action[:3] x 5 cm, orientation offset =
rotation vector action[3:6] x 0.5 rad applied in the world frame (goal = R(delta) @ current). Aiming at a
target is ``(target - current) / scale``, clipped to [-1, 1], plus a damping term (the arm lags its goal and
would overshoot) and an integral term (the controller leaves a steady offset of up to ~2 cm far from the base
and under a held object's weight). The gripper always points down; ``_finger_axis`` is the horizontal direction
the fingers open along.
"""

from __future__ import annotations

import numpy as np

from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.experts.geometry import (
    GAIN_D,
    GAIN_I,
    INTEGRAL_MAX,
    INTEGRATE_WITHIN,
    POS_SCALE,
    POS_TOL,
    ROT_SCALE,
    STALL_STEPS,
    WRIST_MARGIN,
    _down_rotation,
    _rotvec,
)
from vlaprobe.symbols.world import WorldState


class ArmSkill:
    """One skill: a phase machine over the live simulator whose :meth:`act` returns the next (7,) action.

    ``avoid`` names the scene object the skill handles (left out of its obstacles). Subclasses implement
    :meth:`_decide` and set ``phase``; the phase ``"done"`` ends the skill."""

    def __init__(self, env: LiberoTaskEnv, seed: int = 0, avoid: str | None = None) -> None:
        self.env = env
        self.seed = seed
        sim_env = env.sim_env
        robot = sim_env.robots[0]
        self._model = sim_env.sim.model._model
        self._data = sim_env.sim.data._data
        self._eef_site = int(robot.eef_site_id)
        self._gripper_geoms = np.array([self._model.geom(g).id for g in robot.gripper.contact_geoms])
        self._robot_base = self._model.body(robot.robot_model.root_body).id
        self._wrist = self._model.joint(robot.robot_joints[-1])  # turns the hand about its pointing axis
        held = sim_env.obj_body_id[avoid] if avoid is not None else self._robot_base
        self._obstacles = self._obstacle_geoms(self._robot_base, held)
        self.phase = "start"

    def _obstacle_geoms(self, robot_body: int, pick_body: int) -> np.ndarray:
        """Collision geoms the gripper must avoid: all but the robot's and the object to pick."""
        model = self._model
        roots = model.body_rootid[model.geom_bodyid]
        collides = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
        keep = collides & (roots != model.body_rootid[robot_body]) & (roots != model.body_rootid[pick_body])
        return np.flatnonzero(keep)

    def reset(self) -> None:
        """Start the skill from the current state (the controller's memory is cleared)."""
        self._finger_axis = self._current_finger_axis()  # target finger axis (world, horizontal)
        self._anchor = np.zeros(3)  # a phase's fixed target
        self._last_pos = self._eef()[0]  # grip point at the previous step
        self._integral = np.zeros(
            3
        )  # integral of the position error (the arm's steady offset), across phases

    def _enter(self, phase: str) -> None:
        self.phase = phase
        self._phase_steps = 0
        self._best_error = np.inf
        self._stalled = 0

    @property
    def done(self) -> bool:
        return self.phase == "done"

    # ----- reading the simulator -------------------------------------------------------------------------
    def _eef(self) -> tuple[np.ndarray, np.ndarray]:
        """Grip-site position and rotation matrix."""
        data = self._data
        return data.site_xpos[self._eef_site].copy(), data.site_xmat[self._eef_site].reshape(3, 3).copy()

    def _current_finger_axis(self) -> np.ndarray:
        axis = self._data.site_xmat[self._eef_site].reshape(3, 3)[:, 0].copy()  # the fingers open along x
        axis[2] = 0.0
        return axis / np.linalg.norm(axis)

    def _wrist_axis(self, axis: np.ndarray) -> np.ndarray:
        """``axis`` or ``-axis`` (the fingers are symmetric: either grips), whichever the hand, pointing down,
        turns to the least while its last joint stays ``WRIST_MARGIN`` inside its range (turning the world
        yaw by +a turns that joint by -a)."""
        current = self._current_finger_axis()
        q = float(self._data.qpos[self._wrist.qposadr[0]])
        low, high = self._model.jnt_range[self._wrist.id] + np.array([WRIST_MARGIN, -WRIST_MARGIN])
        options = []
        for candidate in (axis, -axis):
            turn = float(
                np.arctan2(current[0] * candidate[1] - current[1] * candidate[0], current @ candidate)
            )
            options.append((not low <= q - turn <= high, abs(turn), candidate))
        return min(options, key=lambda o: (o[0], o[1]))[2]

    def _obstacle_boxes(self, geoms: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World centres, rotations and half sizes of the obstacle geoms' (or ``geoms``') bounding boxes (exact
        for boxes)."""
        model, data = self._model, self._data
        g = self._obstacles if geoms is None else geoms
        rot = data.geom_xmat[g].reshape(-1, 3, 3)
        centre = data.geom_xpos[g] + np.einsum("bij,bj->bi", rot, model.geom_aabb[g, :3])
        return centre, rot, model.geom_aabb[g, 3:]

    def _corridor_top(
        self, a: np.ndarray, b: np.ndarray, width: float, geoms: np.ndarray | None = None
    ) -> float:
        """Highest obstacle (or ``geoms``) top whose footprint comes within ``width`` of the horizontal segment
        a-b."""
        centre, rot, half = self._obstacle_boxes(geoms)
        extent = np.einsum("bij,bj->bi", np.abs(rot), half)
        seg = b[:2] - a[:2]
        t = np.clip(((centre[:, :2] - a[:2]) @ seg) / max(float(seg @ seg), 1e-9), 0.0, 1.0)
        closest = a[:2] + t[:, None] * seg
        gap = np.linalg.norm(np.maximum(np.abs(centre[:, :2] - closest) - extent[:, :2], 0.0), axis=1)
        tops = (centre[:, 2] + extent[:, 2])[gap < width]
        return float(tops.max()) if len(tops) else float(self.env.world_state().table_height)

    # ----- control ---------------------------------------------------------------------------------------
    def _action(self, target: np.ndarray, gripper: float, speed: float = 1.0) -> np.ndarray:
        """Move the grip point towards ``target`` (at most ``speed`` action units), fingers along the plan."""
        pos, rot = self._eef()
        error = (target - pos) / POS_SCALE
        near = np.abs(error) < INTEGRATE_WITHIN  # integrate only the residual, not the travel (no windup)
        self._integral = np.clip(self._integral + GAIN_I * error * near, -INTEGRAL_MAX, INTEGRAL_MAX)
        action = np.zeros(7)
        velocity = (pos - self._last_pos) / POS_SCALE  # per step, in action units
        action[:3] = np.clip(error + self._integral - GAIN_D * velocity, -speed, speed)
        action[3:6] = np.clip(_rotvec(self._goal_rotation() @ rot.T) / ROT_SCALE, -1.0, 1.0)
        action[6] = gripper
        return action

    def _goal_rotation(self) -> np.ndarray:
        """The grip-site frame the arm turns to: pointing down, fingers along ``_finger_axis``."""
        return _down_rotation(self._finger_axis)

    def _stuck(self, error: float) -> bool:
        """Track a shrinking error; True once it has not shrunk by 1 mm for ``STALL_STEPS`` steps."""
        if error < self._best_error - 1e-3:
            self._best_error, self._stalled = error, 0
        else:
            self._stalled += 1
        return self._stalled >= STALL_STEPS

    def _fingers_then(self, pos: np.ndarray, command: float, steps: int, then: str) -> np.ndarray | None:
        """Hold still where the phase began while the fingers follow ``command`` for ``steps`` steps, then
        enter ``then``: the action, or None once entered."""
        if self._phase_steps == 0:
            self._anchor = pos
        if self._phase_steps < steps:
            return self._action(self._anchor, command)
        self._enter(then)
        return None

    def _retreat(self, pos: np.ndarray, command: float) -> np.ndarray | None:
        """Move to the anchor (set on entering the retreat) until there or blocked, then enter ``done``: the
        action, or None once done."""
        error = float(np.linalg.norm(self._anchor - pos))
        if error > POS_TOL and not self._stuck(error):
            return self._action(self._anchor, command)
        self._enter("done")
        return None

    @staticmethod
    def _hold(command: float) -> np.ndarray:
        """Stay still, the fingers following ``command``."""
        action = np.zeros(7)
        action[6] = command
        return action

    def act(self) -> np.ndarray:
        """The (7,) action for the current simulator state."""
        action = self._decide(self.env.world_state())
        self._phase_steps += 1
        self._last_pos = self._eef()[0]
        return action

    def _decide(self, state: WorldState) -> np.ndarray:
        raise NotImplementedError
