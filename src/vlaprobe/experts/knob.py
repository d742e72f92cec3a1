"""Skill: turn an on-off fixture's knob (the flat stove's) on or off by grasping it and turning the wrist.

``approach`` above the knob's axis with the fingers across its handle (the knob body's highest geom),
``descend`` until the grip point is ``KNOB_DEPTH`` below the handle's top, ``close``, ``turn`` the gripper's
yaw about the vertical (the knob's hinge) in the direction LIBERO's rule asks for until the joint is
``KNOB_MARGIN`` past the rule's threshold, ``release`` and ``retreat``. A turn that stalls (the fingers
slipped off the handle) lets go and starts over.
"""

from __future__ import annotations

import numpy as np

from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.experts.base import ArmSkill
from vlaprobe.experts.geometry import (
    APPROACH_ABOVE_RIM,
    CLOSE,
    CLOSE_STEPS,
    KNOB_DEPTH,
    KNOB_MARGIN,
    KNOB_TURN,
    OPEN,
    OPEN_STEPS,
    PHASE_STEPS,
    POS_TOL,
    RETREAT_HEIGHT,
    SETTLED_SPEED,
    YAW_TOL,
    _down_rotation,
    _rotvec,
)
from vlaprobe.symbols.world import WorldState


class Knob(ArmSkill):
    """Turn ``fixture`` on (``on``) or off (module doc)."""

    def __init__(self, env: LiberoTaskEnv, fixture: str, on: bool = True, seed: int = 0) -> None:
        super().__init__(env, seed, avoid=None)
        scene, model = env.scene, self._model
        k = scene.on_off.index(fixture)
        self._k = k
        self._rule = scene.on_off_articulation[k] if on else scene.off_articulation[k]
        self._joint = model.joint(env.sim_env.get_object(fixture).joints[0])
        self._knob_body = int(self._joint.bodyid[0])
        self._raise = not self._rule.below
        geoms = [
            g
            for g in range(model.ngeom)
            if model.geom_bodyid[g] == self._knob_body
            and (model.geom_contype[g] or model.geom_conaffinity[g])
        ]
        self._handle = max(geoms, key=self._geom_top)
        self.reset()

    def _geom_top(self, g: int) -> float:
        rot = self._data.geom_xmat[g].reshape(3, 3)
        centre = self._data.geom_xpos[g] + rot @ self._model.geom_aabb[g, :3]
        return float(centre[2] + np.abs(rot)[2] @ self._model.geom_aabb[g, 3:])

    def reset(self) -> None:
        """Read the knob's pose now (a reset places the fixtures) and start from the current state."""
        super().reset()
        axis = self._data.xmat[self._knob_body].reshape(3, 3) @ np.asarray(self._joint.axis)
        # Raising the joint turns the knob by +angle about ``axis``; the rule says which way to go.
        self._turn_sign = (1.0 if self._raise else -1.0) * float(np.sign(axis[2]) or 1.0)
        self._enter("approach")

    def _holds(self, state: WorldState) -> bool:
        return bool(self._rule.is_active(np.array([state.on_off_qpos[self._k]]))[0])

    def _progress(self, state: WorldState) -> float:
        """The joint's position, signed so that the turn makes it grow."""
        qpos = float(state.on_off_qpos[self._k])
        return qpos if self._raise else -qpos

    def _grip(self) -> np.ndarray:
        """Grip point: over the hinge, ``KNOB_DEPTH`` below the handle's top."""
        point = self._data.xpos[self._knob_body].copy()
        point[2] = self._geom_top(self._handle) - KNOB_DEPTH
        return point

    def _handle_axis(self) -> np.ndarray:
        """Horizontal unit vector across the handle (its narrower horizontal side)."""
        rot = self._data.geom_xmat[self._handle].reshape(3, 3)
        half = self._model.geom_aabb[self._handle, 3:]
        axes = [rot[:, i] for i in range(3) if abs(rot[2, i]) < 0.5]
        sizes = [half[i] for i in range(3) if abs(rot[2, i]) < 0.5]
        axis = axes[int(np.argmin(sizes))].copy()
        axis[2] = 0.0
        return axis / np.linalg.norm(axis)

    def _decide(self, state: WorldState) -> np.ndarray:
        pos, rot = self._eef()
        if self.phase == "approach":
            if self._phase_steps == 0:
                across = self._handle_axis()
                current = self._current_finger_axis()
                self._finger_axis = across if across @ current >= 0 else -across
            above = self._grip() + np.array([0.0, 0.0, APPROACH_ABOVE_RIM])
            turned = np.linalg.norm(_rotvec(_down_rotation(self._finger_axis) @ rot.T)) < YAW_TOL
            settled = np.linalg.norm(pos - self._last_pos) < SETTLED_SPEED
            if (
                np.linalg.norm(above - pos) < POS_TOL and turned and settled
            ) or self._phase_steps > PHASE_STEPS:
                self._enter("descend")
            else:
                return self._action(above, OPEN)
        if self.phase == "descend":
            grip = self._grip()
            error = float(np.linalg.norm(grip - pos))
            if error < 0.004 or self._stuck(error) or self._phase_steps > PHASE_STEPS:
                self._enter("close")
            else:
                return self._action(grip, OPEN)
        if (
            self.phase == "close"
            and (action := self._fingers_then(pos, CLOSE, CLOSE_STEPS, "turn")) is not None
        ):
            return action
        if self.phase == "turn":
            if self._holds(state) and abs(state.on_off_qpos[self._k] - self._rule.threshold) >= KNOB_MARGIN:
                self._enter("release")
            elif self._stuck(-self._progress(state)) or self._phase_steps > PHASE_STEPS:
                self._enter("regrasp")
            else:
                c, s = np.cos(KNOB_TURN * self._turn_sign), np.sin(KNOB_TURN * self._turn_sign)
                x, y = self._current_finger_axis()[:2]
                self._finger_axis = np.array([c * x - s * y, s * x + c * y, 0.0])
                return self._action(self._anchor, CLOSE)
        if self.phase in ("release", "regrasp"):
            if self._phase_steps < OPEN_STEPS:
                return self._action(self._anchor, OPEN)
            if self.phase == "regrasp":
                self._enter("approach")
                return self._action(pos + np.array([0.0, 0.0, 0.03]), OPEN)
            self._anchor = pos + np.array([0.0, 0.0, RETREAT_HEIGHT])
            self._enter("retreat")
        if self.phase == "retreat" and (action := self._retreat(pos, OPEN)) is not None:
            return action
        return self._hold(OPEN)
