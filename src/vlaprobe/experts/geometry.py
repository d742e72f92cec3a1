"""The scripted LIBERO expert's constants and the geometry it plans with (boxes, rims, gripper frames).

Kept apart from :mod:`vlaprobe.experts` (the phase machine) so that each stays readable; the values
are documented where declared.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

POS_SCALE = 0.05  # metres of goal offset per unit of action[:3] (OSC_POSE output_max)
ROT_SCALE = 0.5  # radians of goal rotation per unit of action[3:6]
OPEN, CLOSE = -1.0, 1.0  # gripper commands (action[6])

# Grasp geometry (the LIBERO bowls: ~10.7 cm across, 5 cm tall, thin walls; Panda fingers open 8 cm).
GRASP_DEPTHS = (0.025, 0.02, 0.015)  # grip point below the rim top, preferred first: the pads pinch the upper
# wall; shallower grasps keep the hand (whose underside is 2.6 cm above the grip point) over a drawer's walls
GRIP_INSET = 0.015  # grip point inside the rim radius, so the outer finger reaches less far out
APPROACH_ABOVE_RIM = 0.07  # pre-grasp height of the grip point above the rim top
SUPPORT_SLACK = 0.003  # obstacles are cut this far above the object's bottom when choosing a grasp side
SIDES = 24  # candidate grasp sides around the rim
CLEARANCE_CAP = 0.01  # clearances beyond this count as equally free (metres; the unit of the scores below)
TURN_COST = 0.001  # score per radian of yaw turn
REACH_COST = 0.05  # score per metre of horizontal distance from the robot's base
DEPTH_COST = 0.2  # score per metre of grasp depth given up
BLOCKED_ANGLE = np.deg2rad(40)  # after a blocked descent, sides this close to it are avoided
ARM_MARGIN = 0.02  # the arm's links (predicted at the grasp, ~2 cm off) should stay this far from obstacles
# Motion.
GAIN_D = 1.0  # damping gain on the grip point's velocity: the arm lags its goal, so braking avoids overshoot
GAIN_I = 0.05  # integral gain (action units per step per unit error)
INTEGRAL_MAX = 0.6  # bound of the integral term (action units)
INTEGRATE_WITHIN = 0.5  # integrate an axis's error only when below this (action units, i.e. 2.5 cm)
CLEAR_MARGIN = 0.03  # vertical margin over obstacles while moving sideways
RELEASE_GAP = 0.015  # object bottom above the place target's top when opening
RETREAT_HEIGHT = 0.10  # how far to rise after releasing
CLOSE_STEPS = 12  # steps with the gripper commanded closed before moving
OPEN_STEPS = 8  # steps with the gripper commanded open before moving away
POS_TOL = 0.008  # waypoint reached (metres)
SETTLED_SPEED = 0.003  # metres per step below which the gripper counts as stopped
DESCEND_XY_TOL = 0.005  # horizontal error that pauses a descent
DESCEND_STEP = 0.008  # descent speed (metres per step)
YAW_TOL = 0.06  # orientation reached (radians)
WRIST_MARGIN = 0.15  # the hand's last joint turns no closer than this to its limits (radians)
STALL_STEPS = 8  # steps without 1 mm of progress that end a move (something blocks it)
PHASE_STEPS = 80  # steps after which an approach or descent counts as failed
MIN_OPENING = 0.001  # finger opening (metres) below which the fingers hold nothing
LOST_DISTANCE = 0.02  # grip point this far outside the object's box: the grasp is lost
REPLAN_DISTANCE = 0.03  # the object moved this far (horizontally) since its grasp was planned: plan again
REGION_RADIUS = 0.02  # a region target's top is the highest obstacle this close to its centre
OFF_TARGET = 0.06  # a released object this far (horizontally) from the target's origin is not on it


def _rotvec(rot: np.ndarray) -> np.ndarray:
    """Rotation vector (axis x angle) of a rotation matrix."""
    return Rotation.from_matrix(rot).as_rotvec()


def _box_distance(points: np.ndarray, centre: np.ndarray, rot: np.ndarray, half: np.ndarray) -> np.ndarray:
    """(P, B) distances from points (P, 3) to oriented boxes (B centres, B rotations, B half sizes)."""
    # Coordinates in each box's frame, local[p, b] = rot[b].T @ (points[p] - centre[b]), as one matrix product.
    local = (points @ rot.transpose(1, 0, 2).reshape(3, -1)).reshape(len(points), -1, 3)
    local -= np.einsum("bj,bji->bi", centre, rot)[None]
    outside = np.maximum(np.abs(local) - half[None], 0.0)
    return np.sqrt(np.einsum("pbi,pbi->pb", outside, outside))


def _clip_below(
    centre: np.ndarray, rot: np.ndarray, half: np.ndarray, z: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cut upright boxes (one local axis vertical) at height ``z``, keeping what lies above; boxes wholly below
    go. What the object stands on then no longer counts against a grasp side: the fingertips stay above it."""
    axis = np.argmax(np.abs(rot[:, 2, :]), axis=1)
    rows = np.arange(len(axis))
    upright = np.abs(rot[rows, 2, axis]) > 0.99
    up = rot[rows, :, axis] * np.sign(rot[rows, 2, axis])[:, None]  # the vertical local axis, pointing up
    h = half[rows, axis]
    bottom = np.maximum(centre[:, 2] - h, z)
    top = centre[:, 2] + h
    new_h = np.where(upright, 0.5 * (top - bottom), h)
    shift = np.where(upright, (bottom + top) / 2 - centre[:, 2], 0.0)
    centre = centre + shift[:, None] * up / np.where(upright, up[:, 2], 1.0)[:, None]
    half = half.copy()
    half[rows, axis] = new_h
    keep = ~upright | (top > z)
    return centre[keep], rot[keep], half[keep]


def _down_rotation(finger_axis: np.ndarray) -> np.ndarray:
    """Grip-site frame pointing straight down with the fingers opening along ``finger_axis`` (its x axis)."""
    z = np.array([0.0, 0.0, -1.0])
    return np.stack([finger_axis, np.cross(z, finger_axis), z], axis=1)


# Body grasps (boxes, cans, bottles): the grip point below the object's top.
BODY_DEPTH = 0.03  # at most this far below the top (the hand's underside is ~2.6 cm above the grip point)
BODY_MIN_DEPTH = 0.008  # at least this far below the top (flat boxes: half their height otherwise)
BODY_MAX_SPAN = 0.07  # a body grasp never straddles a wider side (the open fingers take ~8 cm, pads included)

# Knobs (the flat stove's: a bar 7 cm x 2.4 cm on a hinge about the vertical).
KNOB_DEPTH = 0.012  # grip point below the handle's top
KNOB_TURN = 0.25  # yaw the fingers are asked to turn ahead of where they are (radians)
KNOB_MARGIN = 0.15  # turn this far past LIBERO's on/off threshold (radians)

# Pushing (a plate along the table).
PUSH_BEHIND = 0.03  # fingers start this far behind the object's far edge
PUSH_INSET = 0.025  # ... or this far inside it when something stands behind
PUSH_CLEARANCE = (
    0.04  # behind is free when nothing within this distance stands this high over the object's bottom
)
PUSH_HEIGHT = 0.012  # grip point above the object's bottom while pushing
PUSH_INSIDE = 0.5  # done once the object's origin is within this share of the region's half sizes
PUSH_STEP = 0.02  # the fingers aim this far ahead along the way to the region (metres)
PUSH_BLOCKED = 0.02  # a descent stopped this far above its start is blocked (the hand on a handle)
PUSH_DEEPER = 0.015  # ... and the next starts this much deeper inside the rim (twice at most)
PUSH_DRIFT = 0.04  # the object this far off the push line: approach again from behind it

# Drawers (opened by their handle from the front).
DRAWER_PRE = 0.08  # pre-grasp (and retreat) distance in front of the handle
DRAWER_HAND_BELOW = 0.11  # the hand facing a drawer reaches this far below the grip point (+1 cm margin)
TRAVEL_WIDTH = (
    0.13  # obstacles this close (horizontally) to the grip point's path count against its height (the hand
)
# facing a drawer trails 12.4 cm behind the grip point)
TURN_FIRST = 0.3  # the hand turns to face the drawer where it is until within this (radians), then travels
DRAWER_MARGIN = 0.02  # pull this far past LIBERO's open threshold (metres of slide)
DRAWER_SPEED = (
    1.0  # action bound while reaching for the handle and pulling (0.5 took ~20 more steps per opening)
)

# Clearing the way of a drawer (an object standing where the drawer will open over it).
CLEAR_GAP = 0.01  # the object is pushed until its box stands this far outside the opened drawer's box
CLEAR_SIDESTEP = 0.06  # ... and shifted by up to this much along the drawer's other horizontal axis
CLEAR_TOL = 0.02  # half size of the spot it is pushed to (the push ends within PUSH_INSIDE of it)
CLEAR_NEIGHBOUR = 0.005  # the pushed object must stay this far from every other object's box
PUSH_OVER = 0.018  # grip point above a low object behind the pushed one (the fingertips reach 1.2 cm below)
