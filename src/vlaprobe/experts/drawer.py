"""Skill: open or close a drawer (a container region on a slide joint) by its handle, from the front.

The handle is the drawer body's collision geom that stands out farthest along the opening direction (read from
the slide joint and LIBERO's open rule). The gripper turns to point horizontally into the drawer's front with
the fingers opening vertically (a gripper pointing down meets the handles of the drawers above), then:

- open: ``approach`` a point ``DRAWER_PRE`` in front of the handle (first at the current height, then down to the
  handle's), ``insert`` until the grip point is at the handle's centre, ``close`` the fingers on it, ``pull``
  along the opening direction until the joint is ``DRAWER_MARGIN`` past LIBERO's open threshold, ``release``,
  ``retreat`` straight back, then go back to where the skill started (``home``) while turning to point down
  again: the arm's joints return near their usual configuration, from which the next skill starts;
- close: the same approach with closed fingers, then ``push`` the handle in until LIBERO's close rule holds.

A pull that stalls (the fingers slipped off) lets go and approaches again.
"""

from __future__ import annotations

import numpy as np

from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.experts.base import ArmSkill
from vlaprobe.experts.geometry import (
    CLOSE,
    CLOSE_STEPS,
    DRAWER_HAND_BELOW,
    DRAWER_MARGIN,
    DRAWER_PRE,
    DRAWER_SPEED,
    OPEN,
    OPEN_STEPS,
    PHASE_STEPS,
    POS_TOL,
    TRAVEL_WIDTH,
    TURN_FIRST,
    YAW_TOL,
    _down_rotation,
    _rotvec,
)
from vlaprobe.symbols.world import WorldState


def facing_frame(approach: np.ndarray, finger_axis: np.ndarray) -> np.ndarray:
    """Grip-site frame whose z axis points along ``approach`` and whose fingers open along ``finger_axis``."""
    z = approach / np.linalg.norm(approach)
    x = finger_axis - (finger_axis @ z) * z
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


class Drawer(ArmSkill):
    """Open (``opening``) or close the drawer whose region is ``region`` (module doc)."""

    def __init__(self, env: LiberoTaskEnv, region: str, opening: bool = True, seed: int = 0) -> None:
        super().__init__(env, seed, avoid=None)
        scene, model, e = env.scene, self._model, env.sim_env
        self._k = scene.openable.index(region)
        self._opening = opening
        self._rule = scene.container_articulation[self._k] if opening else scene.close_articulation[self._k]
        self._joint = model.joint(e.object_sites_dict[region].joints[0])
        self._body = int(self._joint.bodyid[0])
        self._geoms = [
            g
            for g in range(model.ngeom)
            if model.geom_bodyid[g] == self._body and (model.geom_contype[g] or model.geom_conaffinity[g])
        ]
        fixture = model.body_rootid[self._body]
        self._others = self._obstacles[model.body_rootid[model.geom_bodyid[self._obstacles]] != fixture]
        self.reset()

    def _geom_box(self, g: int) -> tuple[np.ndarray, np.ndarray]:
        """World centre and half extents of a geom's bounding box."""
        rot = self._data.geom_xmat[g].reshape(3, 3)
        centre = self._data.geom_xpos[g] + rot @ self._model.geom_aabb[g, :3]
        return centre, np.abs(rot) @ self._model.geom_aabb[g, 3:]

    def reset(self) -> None:
        """Read the drawer's pose now (a reset places the fixtures) and start from the current state."""
        super().reset()
        self._axis = self._data.xmat[self._body].reshape(3, 3) @ np.asarray(self._joint.axis)
        open_rule = self.env.scene.container_articulation[self._k]
        self._out = (
            -self._axis if open_rule.below else self._axis
        )  # the drawer front moves along this when opening
        self._handle = max(self._geoms, key=lambda g: float(self._geom_box(g)[0] @ self._out))
        up = np.array([0.0, 0.0, 1.0])
        self._home, rot = self._eef()
        frames = [facing_frame(-self._out, s * up) for s in (1.0, -1.0)]
        self._frame = min(frames, key=lambda f: float(np.linalg.norm(_rotvec(f @ rot.T))))
        self._enter("approach")

    def _goal_rotation(self) -> np.ndarray:
        return self._frame

    @property
    def out(self) -> np.ndarray:
        """The horizontal way the drawer's front moves when opening (world)."""
        return self._out

    def opened_box(self) -> tuple[np.ndarray, np.ndarray]:
        """World corners (lo, hi) of the box around the drawer's geoms once opened by this skill
        (``DRAWER_MARGIN`` past LIBERO's open threshold), from its pose at the last :meth:`reset`."""
        rule = self.env.scene.container_articulation[self._k]
        goal = rule.threshold - DRAWER_MARGIN if rule.below else rule.threshold + DRAWER_MARGIN
        shift = (goal - self._qpos(self.env.world_state())) * self._axis
        boxes = [self._geom_box(g) for g in self._geoms]
        lo = np.min([centre - half for centre, half in boxes], axis=0)
        hi = np.max([centre + half for centre, half in boxes], axis=0)
        return lo + shift, hi + shift

    def _qpos(self, state: WorldState) -> float:
        return float(state.container_qpos[self._k])

    def _holds(self, state: WorldState) -> bool:
        qpos = self._qpos(state)
        if not self._rule.is_active(np.array([qpos]))[0]:
            return False
        return not self._opening or abs(qpos - self._rule.threshold) >= DRAWER_MARGIN

    def _decide(self, state: WorldState) -> np.ndarray:
        pos, rot = self._eef()
        grip = self._gripper_command()
        handle, _ = self._geom_box(self._handle)
        if self.phase not in ("release", "retreat", "done") and self._holds(state):
            self._enter("release")
        if self.phase == "approach":
            front = handle + DRAWER_PRE * self._out
            target = front.copy()
            turn = float(np.linalg.norm(_rotvec(self._frame @ rot.T)))
            if np.linalg.norm(front[:2] - pos[:2]) > 0.03:  # in front first, then down
                floor = self._travel_floor(pos, front)
                target[2] = max(pos[2], front[2], floor)
                if turn > TURN_FIRST or pos[2] < floor - 0.02:  # turn (the arm dips) and rise where it is
                    target[:2] = pos[:2]
            turned = bool(turn < YAW_TOL)
            if (np.linalg.norm(front - pos) < POS_TOL and turned) or self._phase_steps > 2 * PHASE_STEPS:
                self._enter("insert")
            else:
                return self._action(target, grip)
        if self.phase == "insert":
            # Opening: the grip point to the handle's centre; closing: push on through it.
            depth = 0.0 if self._opening else -0.2
            target = handle + depth * self._out
            error = float(np.linalg.norm(handle - pos))
            if self._opening and (error < 0.004 or self._stuck(error) or self._phase_steps > PHASE_STEPS):
                self._enter("close")
            elif not self._opening and (
                self._stuck(-float(pos @ -self._out)) or self._phase_steps > PHASE_STEPS
            ):
                self._enter("release")
            else:
                return self._action(target, grip, speed=DRAWER_SPEED)
        if (
            self.phase == "close"
            and (action := self._fingers_then(pos, CLOSE, CLOSE_STEPS, "pull")) is not None
        ):
            return action
        if self.phase == "pull":
            if self._stuck(-float(pos @ self._out)) or self._phase_steps > PHASE_STEPS:
                self._enter("regrasp")
            else:
                return self._action(pos + 0.05 * self._out, CLOSE, speed=DRAWER_SPEED)
        if self.phase in ("release", "regrasp"):
            if self._phase_steps == 0:
                self._anchor = pos
            if self._phase_steps < OPEN_STEPS:
                return self._action(self._anchor, grip if not self._opening else OPEN)
            if self.phase == "regrasp":
                self._enter("approach")
            else:
                self._anchor = pos + DRAWER_PRE * self._out
                self._enter("retreat")
            return self._action(pos, OPEN if self._opening else CLOSE)
        if self.phase == "retreat":
            error = float(np.linalg.norm(self._anchor - pos))
            if error > POS_TOL and not self._stuck(error):
                return self._action(self._anchor, grip)
            self._anchor = self._home.copy()
            self._frame = self._nearest_down(rot)  # the next skill starts pointing down
            self._enter("home")
        if self.phase == "home":
            error = float(np.linalg.norm(self._anchor - pos))
            turned = bool(np.linalg.norm(_rotvec(self._frame @ rot.T)) < YAW_TOL)
            if not (error < POS_TOL and turned) and self._phase_steps < PHASE_STEPS:
                return self._action(self._anchor, grip)
            self._enter("done")
        return self._hold(OPEN)

    def _travel_floor(self, pos: np.ndarray, front: np.ndarray) -> float:
        """The lowest grip height at which the hand, turned to face the drawer (fingers opening vertically: its
        box reaches ``DRAWER_HAND_BELOW`` below the grip point), passes over what stands between it and the
        point in front of the handle; the drawer's own fixture does not count (the hand ends in front of it).
        Lower (or turning on the way: the arm dips ~5 cm while it turns), the hand knocked over a bottle
        (LIBERO-90 task 29, init 3: the ketchup, which then lay where the bowl's free grasp sides were)."""
        return self._corridor_top(pos, front, TRAVEL_WIDTH, self._others) + DRAWER_HAND_BELOW

    def _nearest_down(self, rot: np.ndarray) -> np.ndarray:
        """The pointing-down frame nearest to ``rot`` (fingers along or across the drawer's slide): tilting
        back about the horizontal, not turning the wrist about the vertical as well."""
        side = np.cross(self._out, np.array([0.0, 0.0, 1.0]))
        frames = [_down_rotation(s * a) for a in (self._out, side) for s in (1.0, -1.0)]
        return min(frames, key=lambda f: float(np.linalg.norm(_rotvec(f @ rot.T))))

    def _gripper_command(self) -> float:
        """Open fingers to take the handle; closed ones to push it."""
        return OPEN if self._opening else CLOSE
