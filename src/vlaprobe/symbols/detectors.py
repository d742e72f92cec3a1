"""Ground-truth detectors: a world-state snapshot in, the truth value of every atom out.

Each detector is a vectorized pure function of ``(Scene, WorldState)`` (the action atoms also take what the
:class:`Labeler` remembers of the episode: the object held, whether a released object is settling);
:class:`Labeler` assembles them into the vocabulary's order. Definitions and thresholds (see also
``docs/symbols.md``):

Spatial relations are judged **from the viewpoint of the image the model is given**: OpenVLA's LIBERO
preprocessing rotates the raw agentview render by 180°, and since MuJoCo's raw render is only flipped upside
down, the model's image is the physical camera view mirrored left-right. Each object is reduced to the centre
of its collision-geom bounding box.

- ``left-of(a,b)`` / ``right-of(a,b)``: the horizontal image coordinate of ``a`` (perspective projection,
  normalised to [-1, 1] across the image width) is smaller / larger than ``b``'s by more than
  ``IMAGE_MARGIN`` = 0.02 (1% of the width: ~2.6 px at 256², ~1 cm at the table's distance), so that objects
  straight in line are neither.
- ``behind(a,b)`` / ``in-front-of(a,b)``: ``a`` is farther from / nearer to the camera than ``b`` along the
  camera's viewing direction projected on the table plane, by more than ``DEPTH_MARGIN`` = 1 cm. Depth in the
  table plane rather than along the optical axis, so that stacking (which moves an object up, not back) does
  not change it.
- ``on(a,b)``: LIBERO's own ``On``: ``a``'s body origin is not below ``b``'s, the two touch, and their origins
  are less than 3 cm apart horizontally. For a fixture ``b`` also true when LIBERO's ``On`` holds between ``a``
  and one of ``b``'s surface regions (cabinet top, stove cook region): ``a``'s origin lies over the region
  (within its half extent) between 5 mm below its top and 10 cm above it, and ``a`` touches ``b``. Without
  this, an object resting on a fixture's top is never ``on`` it (the fixture's origin sits at its base).
- ``on-table(a)``: ``a`` touches the table top and is not held (``grasped``). A fixture (cabinet, stove) is
  welded to the world, so MuJoCo computes no contacts for it: it is on the table when the bottom of its box is
  within ``FIXTURE_TABLE_GAP`` = 3 cm of the table top (LIBERO-90's two-layer shelf and the microwave stand on
  collision boxes that start 2.0 cm above it; LIBERO-spatial's cabinet and stove within 1.5 cm).
- ``inside(a,c)``: LIBERO's own ``In``: ``a``'s body origin lies in the drawer's (or receptacle's: basket,
  microwave, caddy compartment) site box (half extents rotated into the world, 1 cm of slack below).
- ``open(c)``, ``turned-on(k)``: LIBERO's thresholds on the joint (a door's, the microwave's, on its hinge): a
  wooden-cabinet drawer is open below -0.14 (``default_open_ranges``), the flat stove is on at 0.5 or more
  (``default_turnon_ranges``), the microwave open below -1.3.
- ``grasped(a)``: the physical grasp, not the gripper command. A finger *touches* ``a`` when MuJoCo reports a
  contact between one of its collision geoms (pad included) and ``a``'s. A grasp **starts** when both fingers
  touch ``a``. It **lasts** while at least one finger still touches it: robosuite's two-pad check flickers
  while a bowl is held by its rim (one pad slides off the thin wall and only the finger's side touches); the
  finger that still presses keeps it held. It also lasts through a **slip**: while a bowl slides down into a
  firmer pinch, both fingers can hang 0.02-0.47 mm off its wall at the instant of a snapshot, closing at
  25-70 mm/s (measured over 30 expert episodes: 13 of 1,669 held rows); a finger within ``SLIP_GAP`` = 1 mm
  while the fingers close faster than ``FINGER_SPEED`` = 5 mm/s keeps the grasp. It **ends** when no finger
  touches ``a`` (nor is catching it), when the fingers open faster than ``FINGER_SPEED`` (letting go: a held
  grip drifts open by under 0.2 mm/s, an open command opens it at 20-45 mm/s), or when they are shut on nothing
  (opening below ``GRIP_MIN_OPENING`` = 2 mm; a bowl's wall holds them ~4.5 mm apart). At most one object is
  grasped: the one already held, else among those both fingers touch the one whose box centre is nearest the
  grip point. When no object has both fingers on it, a finger touching an object stacked on ``a`` (in contact,
  centre higher) counts as touching ``a``: lifting a stack, one finger may press only the top object (LIBERO-90
  task 63, the bowls stacked for the tray). Stateful (the object held at the previous step): :meth:`Labeler.reset` at every episode start.
  **So every grasped row has a finger in contact with ``a`` or within ``SLIP_GAP`` of it**, not always a
  MuJoCo contact (issue #10 asked for that): without the slip rule the 13 rows would split one grasp in two
  (a flicker). ``tests/envs/test_action_labels.py`` checks exactly this bound.
- ``should-move-towards(a)``: exactly one target while the goal ``on(pick, place)`` does not hold: the object
  to pick until it is grasped; then the place target, which **stays** the target after a release until the
  released object comes to rest (``resting``: touching the table or another object, moving slower than
  ``REST_SPEED`` = 1 cm/s and turning slower than ``REST_SPIN`` = 0.1 rad/s; a bowl dropped from 1.5 cm
  rests 4-5 steps later); resting away from the target, the object to pick is the target again. After a
  release the place stays the target until the goal has held ``GOAL_HOLD_STEPS`` = 3 consecutive steps (the
  cognition's default debounce) or the object rests on the place; from then on nothing, also through a bounce
  (episode t07_i02 of the default run: ``on`` 1, 1, 0, 1 read plate, none, plate, none before), until the object
  is grasped again or comes to rest off its place. Without a release, nothing while the goal holds.
"""

from __future__ import annotations

import numpy as np

from vlaprobe.symbols.vocabulary import Vocabulary, build_vocabulary
from vlaprobe.symbols.world import Goal, Scene, WorldState

IMAGE_MARGIN = 0.02
DEPTH_MARGIN = 0.01
ON_XY_RADIUS = 0.03  # LIBERO ObjectState.check_ontop
SURFACE_BELOW, SURFACE_ABOVE = 0.005, 0.10  # LIBERO SiteObject.under
INSIDE_SLACK_BELOW = 0.01  # LIBERO SiteObject.in_box
FIXTURE_TABLE_GAP = 0.03
GRIP_MIN_OPENING = 0.002  # m between the fingers: below, they are shut on nothing
FINGER_SPEED = 0.005  # m/s: opening faster, the fingers let go; closing faster, they chase a slipping object
SLIP_GAP = 0.001  # m: a finger this close to a slipping held object still holds it
REST_SPEED = 0.01  # m/s: a released object moving slower (and turning slower than REST_SPIN) has come to rest
REST_SPIN = 0.1  # rad/s
GOAL_HOLD_STEPS = (
    3  # steps the goal must hold after a release before the place directive ends (= default debounce)
)


def centers(state: WorldState) -> np.ndarray:
    """(N, 3) bounding-box centres of the tabletop objects."""
    return 0.5 * (state.aabb_lo + state.aabb_hi)


def image_x(state: WorldState, points: np.ndarray) -> np.ndarray:
    """Horizontal coordinate of world points in the model's image, in [-1 (left), 1 (right)] across its width.

    The camera frame's columns are (right, up, backwards) of the physical view; the model's image is that
    view mirrored left-right (see module doc), hence the sign flip. The image is square, so the horizontal
    field of view equals ``camera_fovy``.
    """
    rel = (points - state.camera_pos) @ state.camera_mat  # coordinates in the camera frame
    forward = -rel[:, 2]
    tan_half = np.tan(np.deg2rad(state.camera_fovy) / 2.0)
    return -(rel[:, 0] / forward) / tan_half


def table_depth(state: WorldState, points: np.ndarray) -> np.ndarray:
    """Distance from the camera along its viewing direction projected onto the table plane."""
    fwd = -state.camera_mat[:, 2].copy()
    fwd[2] = 0.0
    fwd /= np.linalg.norm(fwd)
    return (points - state.camera_pos) @ fwd


def spatial(state: WorldState) -> dict[str, np.ndarray]:
    """(N, N) matrices of behind, in-front-of, left-of, right-of (entry [a, b] = pred(a, b))."""
    c = centers(state)
    x = image_x(state, c)
    d = table_depth(state, c)
    dx = x[:, None] - x[None, :]
    dd = d[:, None] - d[None, :]
    return {
        "behind": dd > DEPTH_MARGIN,
        "in-front-of": dd < -DEPTH_MARGIN,
        "left-of": dx < -IMAGE_MARGIN,
        "right-of": dx > IMAGE_MARGIN,
    }


def on_matrix(scene: Scene, state: WorldState) -> np.ndarray:
    """(P, N) matrix: on(a, b) for pickupable a and tabletop b (diagonal meaningless)."""
    n_pick = len(scene.pickupable)
    n = len(scene.tabletop)
    pa = state.pos[:n_pick]
    touch = state.contact[:n_pick, :n]
    above = pa[:, None, 2] >= state.pos[None, :, 2]
    near = np.linalg.norm(pa[:, None, :2] - state.pos[None, :, :2], axis=-1) < ON_XY_RADIUS
    result = above & touch & near
    if scene.surfaces:
        index = {name: i for i, name in enumerate(scene.tabletop)}
        n_cont = len(scene.containers)
        for k, region in enumerate(scene.surfaces):
            r = n_cont + k
            # LIBERO's SiteObject.under multiplies by the site matrix (not its transpose); we match it exactly.
            delta = (pa - state.region_pos[r]) @ state.region_mat[r].T
            size = state.region_size[r]
            over = (
                (delta[:, 2] > size[2] - SURFACE_BELOW)
                & (delta[:, 2] < size[2] + SURFACE_ABOVE)
                & np.all(np.abs(delta[:, :2]) < size[:2], axis=1)
            )
            parent = index[scene.region_parent[region]]
            result[:, parent] |= over & touch[:, parent]
    return result


def inside_matrix(scene: Scene, state: WorldState) -> np.ndarray:
    """(P, H) matrix: inside(a, h), LIBERO's ``In`` (the origin in the site's box) for each of ``scene.holders``
    (drawer sites, then receptacle sites)."""
    n_pick, n_cont = len(scene.pickupable), len(scene.containers)
    start = n_cont + len(scene.surfaces)
    rows = np.r_[0:n_cont, start : start + len(scene.receptacles)].astype(int)
    if len(rows) == 0:
        return np.zeros((n_pick, 0), dtype=bool)
    half = np.abs(np.einsum("cij,cj->ci", state.region_mat[rows], state.region_size[rows]))
    lo = state.region_pos[rows] - half
    hi = state.region_pos[rows] + half
    lo[:, 2] -= INSIDE_SLACK_BELOW
    p = state.pos[:n_pick, None, :]
    return np.all((p > lo[None]) & (p < hi[None]), axis=-1)


def grasped_vector(scene: Scene, state: WorldState, held: int = -1) -> np.ndarray:
    """(P,) grasped(a), at most one True, given the object ``held`` at the previous step (-1: none).

    See the module doc: both fingers touching start a grasp, one finger (or fingers closing on a slipping object)
    keeps it, opening fingers end it.
    """
    n_pick = len(scene.pickupable)
    out = np.zeros(n_pick, dtype=bool)
    opening = float(state.gripper_qpos[0] - state.gripper_qpos[1])
    opening_speed = float(state.gripper_qvel[0] - state.gripper_qvel[1])
    if opening <= GRIP_MIN_OPENING or opening_speed > FINGER_SPEED:
        return out
    n = len(scene.tabletop)
    left = state.contact[:n_pick, n + 1]
    right = state.contact[:n_pick, n + 2]
    if 0 <= held < n_pick:
        slipping = opening_speed < -FINGER_SPEED and float(state.finger_gap[held].min()) <= SLIP_GAP
        if left[held] or right[held] or slipping:
            out[held] = True
            return out
    pinched = left & right
    if not pinched.any():  # a stack lifted together: a finger may touch only the object riding on top
        pinched = _through_stack(state, left, n_pick) & _through_stack(state, right, n_pick)
    if pinched.any():
        dist = np.linalg.norm(centers(state)[:n_pick] - state.eef_pos, axis=1)
        out[int(np.argmin(np.where(pinched, dist, np.inf)))] = True
    return out


def _through_stack(state: WorldState, touch: np.ndarray, n_pick: int) -> np.ndarray:
    """(P,) a finger touches ``a``, or an object in contact with ``a`` whose centre is higher (stacked on it)."""
    z = centers(state)[:n_pick, 2]
    above = state.contact[:n_pick, :n_pick] & (z[:, None] > z[None, :])  # [b, a]: b touches a, higher
    return touch | (touch[:, None] & above).any(axis=0)


def resting(scene: Scene, state: WorldState, i: int) -> bool:
    """Object ``i`` has come to rest: it touches the table or another object and barely moves."""
    n = len(scene.tabletop)
    supported = bool(state.contact[i, : n + 1].any())  # tabletop objects and the table (never itself)
    speed = float(np.linalg.norm(state.lin_vel[i]))
    spin = float(np.linalg.norm(state.ang_vel[i]))
    return supported and speed < REST_SPEED and spin < REST_SPIN


class Labeler:
    """Turns world states into label vectors in the vocabulary's order (object head, action head).

    Stateful along an episode (which object is held, whether a released object is still settling): call
    :meth:`reset` at each episode start, then the labeler once per step, in order. Relabelling an episode's
    stored world states with a fresh (or reset) labeler gives the labels recorded with them.
    """

    def __init__(self, scene: Scene, goal: Goal | None) -> None:
        """``goal`` None: the task's goal is not one pick-and-place (LIBERO-goal's ``Open``, LIBERO-10's
        conjunctions); ``should-move-towards`` is then undefined (:attr:`undefined_action_atoms`, all 0)."""
        self.scene = scene
        self.goal = goal
        self.vocabulary: Vocabulary = build_vocabulary(scene)
        n = len(scene.tabletop)
        self._offdiag = ~np.eye(n, dtype=bool)
        pick_index = {a: i for i, a in enumerate(scene.pickupable)}
        table_index = {a: i for i, a in enumerate(scene.tabletop)}
        if goal is not None and (goal.pick not in pick_index or goal.place not in table_index):
            raise ValueError(f"goal {goal} does not name objects of the scene")
        self._pick = pick_index[goal.pick] if goal is not None else -1
        self._place = table_index[goal.place] if goal is not None else -1
        towards = [a for a in self.vocabulary.action_atoms if a.startswith("should-move-towards(")]
        self.undefined_action_atoms: tuple[str, ...] = tuple(towards) if goal is None else ()
        """Action atoms without a definition for this goal (never to be scored as false)."""
        n_pick = len(scene.pickupable)
        self._on_mask = np.ones((n_pick, n), dtype=bool)
        self._on_mask[np.arange(n_pick), np.arange(n_pick)] = False
        holders = scene.holders
        self._inside_mask = np.array(
            [[scene.region_parent.get(c) != a for c in holders] for a in scene.pickupable], dtype=bool
        ).reshape(n_pick, len(holders))
        self.reset()

    def reset(self) -> None:
        """Start a new episode: nothing held, nothing being placed."""
        self._held = -1
        self._placing = False
        self._landed = (
            False  # on its place for GOAL_HOLD_STEPS steps (or at rest on it): no directive any more
        )
        self._on_steps = 0  # consecutive steps on its place, not grasped

    def __call__(self, state: WorldState) -> tuple[np.ndarray, np.ndarray]:
        """(object bits (224,), action bits (12,)) as bool arrays."""
        scene = self.scene
        n = len(scene.tabletop)
        rel = spatial(state)
        on = on_matrix(scene, state)
        grasped = grasped_vector(scene, state, self._held)
        self._held = int(np.argmax(grasped)) if grasped.any() else -1
        held = np.zeros(n, dtype=bool)
        held[: len(grasped)] = grasped
        on_table = state.contact[:n, n].copy()
        n_pick = len(scene.pickupable)
        on_table[n_pick:] |= np.abs(state.aabb_lo[n_pick:, 2] - state.table_height) < FIXTURE_TABLE_GAP
        on_table &= ~held
        inside = inside_matrix(scene, state)[self._inside_mask]
        is_open = np.array(
            [
                a.is_active(q)
                for a, q in zip(
                    scene.container_articulation + scene.door_articulation, state.container_qpos, strict=True
                )
            ],
            dtype=bool,
        )
        turned_on = np.array(
            [a.is_active(q) for a, q in zip(scene.on_off_articulation, state.on_off_qpos, strict=True)],
            dtype=bool,
        )
        obj = np.concatenate(
            [
                rel["behind"][self._offdiag],
                rel["in-front-of"][self._offdiag],
                rel["left-of"][self._offdiag],
                rel["right-of"][self._offdiag],
                on[self._on_mask],
                on_table,
                inside,
                is_open,
                turned_on,
            ]
        )
        towards = np.zeros(n, dtype=bool)
        if self.goal is None:
            return obj, np.concatenate([grasped, towards])
        placed = bool(on[self._pick, self._place])
        if grasped[self._pick]:
            self._placing, self._landed, self._on_steps = True, False, 0
        else:
            self._on_steps = self._on_steps + 1 if placed else 0
            at_rest = resting(scene, state, self._pick)
            self._landed |= placed and (self._on_steps >= GOAL_HOLD_STEPS or at_rest)
            if (self._placing or self._landed) and at_rest:
                self._placing = False
                self._landed = placed  # at rest off its place (knocked off): the object to pick again
        if grasped[self._pick] or (self._placing and not self._landed):
            towards[self._place] = True
        elif not placed and not self._landed:
            towards[self._pick] = True
        act = np.concatenate([grasped, towards])
        return obj, act

    def as_dict(self, state: WorldState) -> tuple[dict[str, int], dict[str, int]]:
        """Atom name -> 0/1 for both heads (one labeler step, like calling the labeler)."""
        obj, act = self(state)
        return (
            dict(zip(self.vocabulary.object_atoms, obj.astype(int).tolist(), strict=True)),
            dict(zip(self.vocabulary.action_atoms, act.astype(int).tolist(), strict=True)),
        )
