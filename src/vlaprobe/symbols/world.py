"""What the detectors see: a typed scene (static) and a world-state snapshot (one per step).

Detectors are pure functions of a :class:`Scene` and a :class:`WorldState`, so they can be unit-tested on
hand-made states without a simulator. The environment stage (``vlaprobe.envs``) fills both from MuJoCo.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

FINGER_GAP_MAX = 0.01
"""Finger-object distances beyond this (metres) are recorded as this."""

# Extra rows/columns of ``WorldState.contact`` after the tabletop objects, in this order.
TABLE, LEFT_FINGER, RIGHT_FINGER = "table", "left_finger", "right_finger"
EXTRA_CONTACT_BODIES: tuple[str, ...] = (TABLE, LEFT_FINGER, RIGHT_FINGER)


@dataclass(frozen=True)
class Articulation:
    """When a joint counts as open / closed / on / off, in LIBERO's own terms.

    Active when ``qpos < threshold`` if ``below`` else when ``qpos > threshold``, or equal to it too unless
    ``strict``. LIBERO's cabinets open as their drawer joint goes below -0.14 (strictly); its stove is on when the
    knob joint reaches 0.5 (0.5 included); its cabinets are closed above 0.0 (strictly). ``strict`` defaults to
    ``below`` (the two rules LIBERO-spatial has).
    """

    threshold: float
    below: bool
    strict: bool | None = None

    def __post_init__(self) -> None:
        if self.strict is None:
            object.__setattr__(self, "strict", self.below)

    def is_active(self, qpos: np.ndarray) -> np.ndarray:
        if self.below:
            return qpos < self.threshold if self.strict else qpos <= self.threshold
        return qpos > self.threshold if self.strict else qpos >= self.threshold


@dataclass(frozen=True)
class Scene:
    """The typed objects of a task, read from its BDDL problem (``vlaprobe.envs.bddl_scene``).

    LIBERO-spatial: 5 pickupable objects, 2 fixtures (cabinet, stove), 3 drawers, 2 surfaces, 1 on-off object.
    """

    pickupable: tuple[str, ...]
    """Movable objects (BDDL ``:objects``), in BDDL order."""
    fixtures: tuple[str, ...]
    """Fixtures standing on the table (BDDL ``:fixtures`` except the table itself), in BDDL order."""
    containers: tuple[str, ...]
    """Fixture regions that sit on a joint (drawers), e.g. ``wooden_cabinet_1_top_region``."""
    container_articulation: tuple[Articulation, ...]
    """Open rule of each container, same order."""
    surfaces: tuple[str, ...] = ()
    """Fixture regions without a joint that objects can rest on (the cabinet's top, the stove's cook region)."""
    on_off: tuple[str, ...] = ()
    """Fixtures that can be turned on (the stove)."""
    on_off_articulation: tuple[Articulation, ...] = ()
    """Turn-on rule of each on-off fixture, same order."""
    region_parent: dict[str, str] = field(default_factory=dict)
    """Object each container/surface/receptacle region belongs to."""
    receptacles: tuple[str, ...] = ()
    """Regions without a joint that objects go ``In`` (a basket's contain region, a microwave's heating region, a
    desk caddy's compartments, a shelf's layers), in BDDL order. None in LIBERO-spatial."""
    doors: tuple[str, ...] = ()
    """Fixtures whose own joint opens (the microwave's door), not one of their regions. None in LIBERO-spatial."""
    door_articulation: tuple[Articulation, ...] = ()
    """Open rule of each door, same order."""
    close_articulation: tuple[Articulation, ...] = ()
    """LIBERO's ``Close`` rule of each container then each door (not the negation of open: a drawer half out is
    neither); empty in scenes stored before issue #35."""
    off_articulation: tuple[Articulation, ...] = ()
    """LIBERO's ``TurnOff`` rule of each on-off fixture, same order; empty in scenes stored before issue #35."""

    @property
    def tabletop(self) -> tuple[str, ...]:
        """Objects the spatial relations range over: pickupables then fixtures."""
        return self.pickupable + self.fixtures

    @property
    def regions(self) -> tuple[str, ...]:
        """All regions whose poses a world state carries: containers, surfaces, then receptacles."""
        return self.containers + self.surfaces + self.receptacles

    @property
    def openable(self) -> tuple[str, ...]:
        """What ``open`` ranges over: containers (drawers) then doors; ``WorldState.container_qpos`` follows."""
        return self.containers + self.doors

    @property
    def holders(self) -> tuple[str, ...]:
        """What ``inside`` ranges over: containers then receptacles."""
        return self.containers + self.receptacles


@dataclass(frozen=True)
class Goal:
    """The task goal ``On(pick, place)`` (every LIBERO-spatial task)."""

    pick: str
    place: str


@dataclass
class WorldState:
    """A snapshot of everything the detectors need at one step. Arrays follow ``scene`` orders.

    Positions are world coordinates in metres (MuJoCo frame: x towards the agentview camera, z up).
    """

    pos: np.ndarray
    """(N, 3) body origins of ``scene.tabletop`` (what LIBERO's predicates compare)."""
    aabb_lo: np.ndarray
    """(N, 3) lower corner of each tabletop object's world axis-aligned box over its collision geoms."""
    aabb_hi: np.ndarray
    """(N, 3) upper corner, same."""
    contact: np.ndarray
    """(N + 3, N + 3) symmetric bool: tabletop objects, then table, left finger, right finger in contact (a finger
    is any of its collision geoms, pad included)."""
    region_pos: np.ndarray
    """(R, 3) site positions of ``scene.regions``."""
    region_mat: np.ndarray
    """(R, 3, 3) site rotation matrices."""
    region_size: np.ndarray
    """(R, 3) site half sizes (MuJoCo box size)."""
    container_qpos: np.ndarray
    """(C + D,) joint position of each container's joint, then of each door's (``Scene.openable``)."""
    on_off_qpos: np.ndarray
    """(K,) joint position of each on-off fixture's joint."""
    camera_pos: np.ndarray
    """(3,) agentview camera position."""
    camera_mat: np.ndarray
    """(3, 3) camera frame in world coordinates (columns: image right, image up, backwards), MuJoCo's cam_xmat."""
    camera_fovy: float
    """Vertical field of view in degrees."""
    eef_pos: np.ndarray
    """(3,) end-effector position."""
    gripper_qpos: np.ndarray
    """(2,) finger joint positions (left ~+0.04, right ~-0.04 when fully open; both ~0 when closed on nothing):
    the opening between the fingers is ``gripper_qpos[0] - gripper_qpos[1]``."""
    gripper_qvel: np.ndarray
    """(2,) finger joint velocities (m/s); the fingers are opening when ``gripper_qvel[0] - gripper_qvel[1] > 0``."""
    finger_gap: np.ndarray
    """(P, 2) distance from the left / right finger (its collision geoms, pad included) to each pickupable object
    (metres; <= 0 when they touch, i.e. MuJoCo reports a contact; capped at ``FINGER_GAP_MAX``)."""
    gripper_command: float
    """Last gripper command sent (-1 open, +1 close); -1 after a reset. Recorded, not used by the detectors."""
    lin_vel: np.ndarray
    """(N, 3) linear velocity of each tabletop object's body origin (world frame, m/s; 0 for welded fixtures)."""
    ang_vel: np.ndarray
    """(N, 3) angular velocity of each tabletop object (world frame, rad/s)."""
    table_height: float
    """Height of the table top (z of its collision box's upper face)."""
