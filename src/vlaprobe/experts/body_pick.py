"""Skill: pick a box, can or bottle from above by its body and place it on or into a target.

The rim grasp's phase machine (:class:`~vlaprobe.experts.rim_pick.RimPickPlace`: approach, descend, close,
lift, carry, lower, release, retreat, and starting over when the object slips or moves) with another grasp:
the grip point is the centre of the object's box, ``BODY_DEPTH`` below its top (half its height for flat
objects), and the fingers close across the box's narrower horizontal side. A descent stopped early (a
neighbour, the floor) grasps the other side next, unless that side is wider than ``BODY_MAX_SPAN`` (7 cm).
"""

from __future__ import annotations

import numpy as np

from vlaprobe.experts.geometry import (
    APPROACH_ABOVE_RIM,
    BODY_DEPTH,
    BODY_MAX_SPAN,
    BODY_MIN_DEPTH,
    CLEARANCE_CAP,
)
from vlaprobe.experts.rim_pick import RimPickPlace

X_AXIS, Y_AXIS = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])


class BodyPickPlace(RimPickPlace):
    """Pick ``pick`` by its body (module doc) and place it on ``place``."""

    def _enter(self, phase: str) -> None:
        super()._enter(phase)
        if phase == "regrasp":  # a grasp pressed against the table winds the integral up: the approach stalls
            self._integral = np.zeros(3)

    def _grasp_point(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        point = 0.5 * (lo + hi)
        point[2] = hi[2] - self._depth
        return point

    def _choose_side(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """Close across the narrower horizontal side of the box, unless the other side (at most
        ``BODY_MAX_SPAN`` wide: the fingers would straddle what they cannot take) keeps the gripper, swept from
        the approach height down to the grasp, clearer of every other geom (an item beside the basket's wall:
        the hand spans the finger axis), or the narrower side's descent was blocked."""
        self._plan_xy = 0.5 * (lo[:2] + hi[:2])
        size = hi - lo
        self._depth = min(BODY_DEPTH, max(0.5 * float(size[2]), BODY_MIN_DEPTH))
        axis = X_AXIS if size[0] <= size[1] else Y_AXIS
        other = Y_AXIS if axis is X_AXIS else X_AXIS
        if float(other[:2] @ size[:2]) <= BODY_MAX_SPAN:
            blocked = [any(abs(float(a @ b)) > 0.5 for b in self._blocked) for a in (axis, other)]
            if blocked[0] != blocked[1]:
                axis = other if blocked[0] else axis
            else:
                sweep = self._sweep(lo, hi, np.linspace(-self._depth, APPROACH_ABOVE_RIM, 7))
                grip = np.append(0.5 * (lo[:2] + hi[:2]), hi[2])
                free = [
                    min(float(sweep(grip, self._wrist_axis(a)).min()), CLEARANCE_CAP) for a in (axis, other)
                ]
                axis = other if free[1] > free[0] else axis
        self._blocked.clear()
        self._side = axis
        self._finger_axis = self._wrist_axis(axis)
