"""Skill: pick a bowl (or a mug) by its rim and place it on or into a target; reads poses from the simulator.

It solves every LIBERO-spatial task (``On(bowl, plate)``) and the bowl goals of LIBERO-goal (onto the stove,
the cabinet, the plate, into a drawer) with one phase machine whose every decision is derived from the goal
and the live scene, never from the task index:

1. ``approach``: choose the side of the object's rim and the grasp depth (1.5-2.5 cm below the rim) where the
   gripper's collision boxes, swept from the pre-grasp height down to the grasp, stay clear of every other
   geom (a drawer's walls, the cabinet's roof, a neighbouring bowl); turn the gripper's yaw so the fingers
   straddle the rim there (one finger inside the bowl, one outside) and move above that point, high enough to
   pass over whatever stands on the way.
2. ``descend`` (re-centring whenever the arm drifts sideways) and ``close`` the fingers on the wall. A descent
   stopped early by a collision marks that side as blocked and starts over from another side.
3. ``lift`` straight up until the object's bottom clears everything between it and the place target (which
   also takes it out of a drawer: the drawer's walls stand higher than the rim, so pulling it out sideways
   would hook the wall), ``carry`` until its origin is over the target's, ``lower`` it to ``RELEASE_GAP`` above
   the target's top, ``release``, ``retreat`` upwards and hold still (``done``).

If the object slips out of the fingers (or is dropped), moves before it is grasped (a displacement), or leaves
the target after the release (knocked off), the expert opens, rises (``regrasp``) and starts over from where
the object now is.

The controller (actions, damping, integral term) is :class:`~vlaprobe.experts.base.ArmSkill`'s.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.experts.arm import ArmModel
from vlaprobe.experts.base import ArmSkill
from vlaprobe.experts.geometry import (
    APPROACH_ABOVE_RIM,
    ARM_MARGIN,
    BLOCKED_ANGLE,
    CLEAR_MARGIN,
    CLEARANCE_CAP,
    CLOSE,
    CLOSE_STEPS,
    DEPTH_COST,
    DESCEND_STEP,
    DESCEND_XY_TOL,
    GRASP_DEPTHS,
    GRIP_INSET,
    LOST_DISTANCE,
    MIN_OPENING,
    OFF_TARGET,
    OPEN,
    OPEN_STEPS,
    PHASE_STEPS,
    POS_TOL,
    REACH_COST,
    REGION_RADIUS,
    RELEASE_GAP,
    REPLAN_DISTANCE,
    RETREAT_HEIGHT,
    SETTLED_SPEED,
    SIDES,
    SUPPORT_SLACK,
    TURN_COST,
    YAW_TOL,
    _box_distance,
    _clip_below,
    _down_rotation,
    _rotvec,
)
from vlaprobe.experts.targets import Target, find_target
from vlaprobe.symbols.world import WorldState


class RimPickPlace(ArmSkill):
    """Pick ``pick`` by its rim and place it on ``place`` (see module doc).

    ``seed`` rotates the candidate grasp sides by a random fraction of their spacing, so that different seeds
    give slightly different (equally valid) trajectories. ``phase`` names the current phase (for logs).
    """

    def __init__(self, env: LiberoTaskEnv, pick: str, place: Target, seed: int = 0) -> None:
        super().__init__(env, seed, avoid=pick)
        self._arm = ArmModel(env, self._eef_site, self._gripper_geoms)
        self._pick = env.scene.tabletop.index(pick)
        self._goal_target = self._target = place
        self.reset()

    # ----- episode ---------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Start a new episode (call after ``env.reset``)."""
        super().reset()
        self.rng = np.random.default_rng(self.seed)
        self._target = self._goal_target  # undo a retarget
        self._side: np.ndarray | None = None  # unit vector from the object's centre to the grasp side
        self._depth = GRASP_DEPTHS[0]  # grasp depth below the rim
        self._blocked: list[np.ndarray] = []  # sides where a descent was stopped by a collision
        self._plan_xy = np.zeros(2)  # the object's box centre when its grasp side was chosen
        self._enter("approach")

    def _place_top(self, state: WorldState, place: np.ndarray) -> float:
        """Height of the place target's top: an object's box top; for a region, the highest obstacle there."""
        if not self._target.region:
            return float(state.aabb_hi[self._target.index][2])
        return self._corridor_top(place, place, REGION_RADIUS)

    def _gripper_points(self) -> np.ndarray:
        """(P, 3) points on the surfaces of the gripper's collision boxes (hand, fingers; the pads lie inside the
        fingers' boxes) in the grip-site frame."""
        model, data = self._model, self._data
        site_pos, site_rot = self._eef()
        grid = np.stack(np.meshgrid(*[np.linspace(-1.0, 1.0, 5)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
        grid = grid[np.abs(grid).max(axis=1) == 1.0]
        boxes = []
        for g in self._gripper_geoms:
            rot = data.geom_xmat[g].reshape(3, 3)
            world = data.geom_xpos[g] + (model.geom_aabb[g, :3] + grid * model.geom_aabb[g, 3:]) @ rot.T
            boxes.append((world - site_pos) @ site_rot)
        inside = [
            any(
                np.all(b.min(0) >= o.min(0) - 1e-6) and np.all(b.max(0) <= o.max(0) + 1e-6)
                for o in boxes
                if o is not b
            )
            for b in boxes
        ]
        return np.concatenate([b for b, dropped in zip(boxes, inside, strict=True) if not dropped])

    # ----- planning --------------------------------------------------------------------------------------
    @staticmethod
    def _rim(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, float]:
        """Centre and rim radius of the object's bounding box."""
        return 0.5 * (lo + hi), 0.25 * float((hi[0] - lo[0]) + (hi[1] - lo[1]))

    def _grasp_point(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        assert self._side is not None
        centre, radius = self._rim(lo, hi)
        point = centre + (radius - GRIP_INSET) * self._side
        point[2] = hi[2] - self._depth
        return point

    def _choose_side(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """Choose the grasp side and depth: the gripper, swept from the approach height down to the grasp, must
        stay clear of every other geom (up to ``CLEARANCE_CAP``); then deeper grasps, smaller yaw turns and
        sides nearer the robot win (far reaches run into the elbow's limit)."""
        self._plan_xy = 0.5 * (lo[:2] + hi[:2])
        centre, radius = self._rim(lo, hi)
        # Grip heights (relative to the rim) at which the gripper is checked: the candidate depths, then the
        # way up to the approach height. A grasp's clearance is the least over its depth and every level above.
        levels = np.concatenate(
            [-np.array(GRASP_DEPTHS), np.linspace(-GRASP_DEPTHS[-1], APPROACH_ABOVE_RIM, 6)[1:]]
        )
        sweep = self._sweep(lo, hi, levels)

        current = self._current_finger_axis()
        base = self._data.xpos[self._robot_base]
        angles = 2 * np.pi * (np.arange(SIDES) + self.rng.uniform(-0.5, 0.5)) / SIDES
        sides = np.stack([np.cos(angles), np.sin(angles), np.zeros(SIDES)], axis=1)
        candidates: list[tuple[float, int, float, np.ndarray]] = []  # (score, side, depth, grip point)
        for k, side in enumerate(sides):
            axis = self._wrist_axis(side)
            grip = centre + (radius - GRIP_INSET) * side
            grip[2] = hi[2]
            per_level = sweep(grip, axis)
            turn = float(np.arccos(np.clip(axis @ current, -1.0, 1.0)))
            reach = float(np.linalg.norm(grip[:2] - base[:2]))
            blocked = any(side @ b > np.cos(BLOCKED_ANGLE) for b in self._blocked)
            for depth in GRASP_DEPTHS:
                clearance = float(per_level[levels >= -depth - 1e-9].min())
                score = (
                    min(clearance, CLEARANCE_CAP)
                    - TURN_COST * turn
                    - REACH_COST * reach
                    - DEPTH_COST * (GRASP_DEPTHS[0] - depth)
                    - (1.0 if blocked else 0.0)
                )
                candidates.append((score, k, depth, grip - np.array([0.0, 0.0, depth])))
        k, self._depth = self._clear_for_arm(candidates, sides)
        self._side = sides[k]
        self._finger_axis = self._wrist_axis(sides[k])

    def _sweep(
        self, lo: np.ndarray, hi: np.ndarray, levels: np.ndarray
    ) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """A function of (grip point at the object's top, finger axis) giving, per grip height in ``levels``
        (relative to that point), the least distance of the gripper's collision boxes from every other geom
        (1 where none is near). What the object (``lo``, ``hi``) stands on is cut away: the fingertips stay
        above it."""
        gripper = self._gripper_points()
        # Only geoms that reach up into the swept height matter (those below were cut at the object's bottom).
        box_centre, box_rot, box_half = _clip_below(*self._obstacle_boxes(), lo[2] + SUPPORT_SLACK)
        extent = np.einsum("bij,bj->bi", np.abs(box_rot), box_half)
        top = hi[2] + float(levels.max()) - float(gripper[:, 2].min()) + CLEARANCE_CAP  # site z points down
        low = box_centre[:, 2] - extent[:, 2] < top
        box_centre, box_rot, box_half, extent = box_centre[low], box_rot[low], box_half[low], extent[low]
        reach_xy = float(np.linalg.norm(gripper[:, :2], axis=1).max()) + CLEARANCE_CAP
        up = np.array([0.0, 0.0, 1.0])

        def clearance(grip: np.ndarray, axis: np.ndarray) -> np.ndarray:
            # Geoms within the gripper's horizontal reach from this grip point.
            gap_xy = np.maximum(np.abs(box_centre[:, :2] - grip[:2]) - extent[:, :2], 0.0)
            near = np.linalg.norm(gap_xy, axis=1) < reach_xy
            if not near.any():
                return np.ones(len(levels))
            points = grip + levels[:, None, None] * up + gripper @ _down_rotation(axis).T
            distance = _box_distance(points.reshape(-1, 3), box_centre[near], box_rot[near], box_half[near])
            return distance.reshape(len(levels), -1).min(axis=1)

        return clearance

    def _clear_for_arm(
        self, candidates: list[tuple[float, int, float, np.ndarray]], sides: np.ndarray
    ) -> tuple[int, float]:
        """The best (side, depth) once the arm's links at each grasp are scored too (``_arm_penalty``): the
        candidates are checked best first, until none left unchecked can still win (the arm only lowers a
        score)."""
        best, best_score = (candidates[0][1], candidates[0][2]), -np.inf
        for score, k, depth, grip in sorted(candidates, key=lambda c: -c[0]):
            if score <= best_score:
                break
            score -= self._arm_penalty(grip, self._wrist_axis(sides[k]))
            if score > best_score:
                best, best_score = (k, depth), score
        return best

    def _arm_penalty(self, grip: np.ndarray, finger_axis: np.ndarray) -> float:
        """How far inside ``ARM_MARGIN`` of an obstacle the arm's links (elbow, forearm, wrist: not the gripper)
        come with the grip point at ``grip`` (0 when farther): a forearm can reach into a drawer's front above
        the object while the gripper is clear (LIBERO-90 task 29)."""
        clearance = self._arm.clearance(grip, _down_rotation(finger_axis), self._obstacles, ARM_MARGIN)
        return max(ARM_MARGIN - clearance, 0.0)

    def _block_side(self) -> None:
        """Give up the current grasp side: back off and plan again avoiding it."""
        assert self._side is not None
        self._blocked.append(self._side)
        self._side = None
        self._enter("regrasp")

    def _holding(self, state: WorldState, pos: np.ndarray) -> bool:
        """The fingers still hold the object: not shut on nothing, and the grip point at the object."""
        opening = float(state.gripper_qpos[0] - state.gripper_qpos[1])
        lo, hi = state.aabb_lo[self._pick], state.aabb_hi[self._pick]
        outside = np.linalg.norm(np.maximum(np.maximum(lo - pos, pos - hi), 0.0))
        return bool(opening > MIN_OPENING and outside < LOST_DISTANCE)

    def retarget(self, name: str) -> None:
        """Place the object on scene object or region ``name`` instead of the goal's, until the next reset (a
        fault: ``--expert-faults``)."""
        self._target = find_target(self.env, name)

    def _approach(
        self, lo: np.ndarray, hi: np.ndarray, pos: np.ndarray, rot: np.ndarray
    ) -> np.ndarray | None:
        """Above the grasp point, turned and settled: the action, or None once the phase changed."""
        if self._side is None:
            self._choose_side(lo, hi)
        grasp = self._grasp_point(lo, hi)
        if self._phase_steps == 0:  # travel height: above the rim and whatever stands on the way
            clear = self._corridor_top(pos, grasp, 0.06) + CLEAR_MARGIN
            self._anchor[2] = max(hi[2] + APPROACH_ABOVE_RIM, clear)
        height = self._anchor[2]
        above = np.array([grasp[0], grasp[1], height])
        if pos[2] < height - 0.02 and np.linalg.norm(above[:2] - pos[:2]) > 0.03:
            above[:2] = pos[:2]  # rise before moving sideways
        turned = np.linalg.norm(_rotvec(_down_rotation(self._finger_axis) @ rot.T)) < YAW_TOL
        settled = np.linalg.norm(pos - self._last_pos) < SETTLED_SPEED
        above_grasp = np.linalg.norm(grasp[:2] - pos[:2]) < POS_TOL and abs(height - pos[2]) < 0.02
        if above_grasp and turned and settled:
            self._enter("descend")
            return None
        if self._phase_steps > PHASE_STEPS:
            self._block_side()  # unreachable from here
            return None
        return self._action(above, OPEN)

    def _descend(self, lo: np.ndarray, hi: np.ndarray, pos: np.ndarray) -> np.ndarray | None:
        """Down to the grasp point (re-centring first): the action, or None once the phase changed."""
        grasp = self._grasp_point(lo, hi)
        if self._phase_steps == 0:
            self._anchor = pos  # its height is the descent's set point, lowered step by step
        if np.linalg.norm(grasp[:2] - pos[:2]) < DESCEND_XY_TOL:  # re-centre first: far out the arm lags
            self._anchor[2] = max(grasp[2], self._anchor[2] - DESCEND_STEP)
        height = pos[2] - grasp[2]
        if height < 0.004:
            self._enter("close")
            return None
        if (self._anchor[2] <= grasp[2] and self._stuck(height)) or self._phase_steps > PHASE_STEPS:
            if height < 0.01:  # close enough: the pads still reach the wall
                self._enter("close")
            else:  # something is in the way of this side
                self._block_side()
            return None
        return self._action(np.array([grasp[0], grasp[1], self._anchor[2]]), OPEN)

    def _let_go(self, pos: np.ndarray) -> np.ndarray | None:
        """Open the fingers, then rise: the action, or None once done."""
        if self.phase == "release":
            if self._phase_steps == 0:
                self._anchor = pos
            if self._phase_steps < OPEN_STEPS:
                return self._action(self._anchor, OPEN)
            self._anchor = pos + np.array([0.0, 0.0, RETREAT_HEIGHT])
            self._enter("retreat")

        if self.phase == "retreat":
            error = float(np.linalg.norm(self._anchor - pos))
            if error < POS_TOL or self._stuck(error):
                self._enter("done")
            else:
                return self._action(self._anchor, OPEN)
        return None

    def _decide(self, state: WorldState) -> np.ndarray:
        lo, hi = state.aabb_lo[self._pick], state.aabb_hi[self._pick]
        obj, place = state.pos[self._pick], self._target.point(state, self._data)
        pos, rot = self._eef()

        if self.phase in ("lift", "carry", "lower") and not self._holding(state, pos):
            self._enter("regrasp")
        moved = np.linalg.norm(0.5 * (lo[:2] + hi[:2]) - self._plan_xy) > REPLAN_DISTANCE
        if self.phase in ("approach", "descend") and self._side is not None and moved:
            self._side = None  # displaced before the grasp: choose a side at its new place
            self._enter("regrasp")
        if self.phase in ("retreat", "done") and np.linalg.norm(obj[:2] - place[:2]) > OFF_TARGET:
            self._side = None  # knocked off the target after the release: pick it up again
            self._enter("regrasp")

        if self.phase == "approach" and (action := self._approach(lo, hi, pos, rot)) is not None:
            return action
        if self.phase == "descend" and (action := self._descend(lo, hi, pos)) is not None:
            return action

        if self.phase == "close":
            if self._phase_steps == 0:
                self._anchor = pos
            if self._phase_steps < CLOSE_STEPS:
                return self._action(self._anchor, CLOSE)
            if self._holding(state, pos):
                self._enter("lift")
            else:
                self._side = None
                self._enter("regrasp")

        others_top = self._corridor_top(obj, place, 0.5 * float(hi[0] - lo[0]) + 0.03)
        carry_z = pos[2] + (others_top + CLEAR_MARGIN - lo[2])  # grip height that puts the bottom there
        if self.phase == "lift":
            if self._phase_steps == 0:
                self._anchor = pos  # lift straight up from here
            if pos[2] > carry_z - 0.01 or self._stuck(abs(carry_z - pos[2])):
                self._enter("carry")
            else:
                return self._action(np.array([self._anchor[0], self._anchor[1], carry_z]), CLOSE)

        offset = np.append(place[:2] - obj[:2], 0.0)
        if self.phase == "carry":
            if np.linalg.norm(offset) < 0.01:
                self._enter("lower")
            else:
                target = pos + offset
                target[2] = max(carry_z, pos[2])
                return self._action(target, CLOSE)

        if self.phase == "lower":
            place_top = self._place_top(state, place)
            gap = lo[2] - (place_top + RELEASE_GAP)
            if gap < 0.003 or self._stuck(gap):
                self._enter("release")
            else:
                target = pos + offset
                target[2] = pos[2] - gap
                return self._action(target, CLOSE, speed=1.0 if gap > 0.05 else 0.5)

        if self.phase in ("release", "retreat") and (action := self._let_go(pos)) is not None:
            return action

        if self.phase == "regrasp":
            if self._phase_steps == 0:
                self._anchor = pos + np.array([0.0, 0.0, 0.05])
            if self._phase_steps < OPEN_STEPS:
                return self._action(self._anchor, OPEN)
            self._enter("approach")
            return self._decide(state)

        action = np.zeros(7)  # done: hold still, open
        action[6] = OPEN
        return action
