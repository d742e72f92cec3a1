"""Detectors on hand-made world states: each predicate, its thresholds and edge cases."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vlaprobe.symbols import Articulation, Goal, Labeler, Scene, WorldState, build_vocabulary
from vlaprobe.symbols.detectors import image_x

# A LIBERO-spatial-like scene: 5 pickupables, cabinet (3 drawers, a top) and stove (cook region, knob).
DRAWERS = ("cab_top_region", "cab_middle_region", "cab_bottom_region")
SCENE = Scene(
    pickupable=("bowl", "bowl2", "box", "ramekin", "plate"),
    fixtures=("cab", "stove"),
    containers=DRAWERS,
    container_articulation=(Articulation(-0.14, below=True),) * 3,
    surfaces=("cab_top_side", "stove_cook_region"),
    on_off=("stove",),
    on_off_articulation=(Articulation(0.5, below=False),),
    region_parent={**{d: "cab" for d in DRAWERS}, "cab_top_side": "cab", "stove_cook_region": "stove"},
)
GOAL = Goal(pick="bowl", place="plate")
N = len(SCENE.tabletop)
IDX = {name: i for i, name in enumerate(SCENE.tabletop)}
TABLE, LEFT = N, N + 1
# LIBERO's agentview camera: at +x looking back and down at the table; image right = world +y.
CAM_MAT = np.array([[0.0, -0.628266, 0.777998], [1.0, 0.0, 0.0], [0.0, 0.777998, 0.628266]])
TABLE_Z = 0.9


def make_state(**overrides: object) -> WorldState:
    """Objects spread on the table 20 cm apart along y, 5 cm cubes resting on it, nothing touching."""
    pos = np.array([[0.0, -0.45 + 0.15 * i, TABLE_Z] for i in range(N)])
    half = np.full((N, 3), 0.025)
    state = WorldState(
        pos=pos,
        aabb_lo=pos - half * np.array([1, 1, 0]),
        aabb_hi=pos + half * np.array([1, 1, 2]),
        contact=np.zeros((N + 3, N + 3), dtype=bool),
        region_pos=np.array([[0.0, 0.3, 1.0]] * 3 + [[0.0, 0.3, 1.2], [0.0, 0.45, 0.91]]),
        region_mat=np.stack([np.eye(3)] * 5),
        region_size=np.array([[0.03, 0.075, 0.1]] * 3 + [[0.12, 0.09, 0.0015], [0.075, 0.075, 0.0025]]),
        container_qpos=np.zeros(3),
        on_off_qpos=np.zeros(1),
        camera_pos=np.array([0.6586, 0.0, 1.61]),
        camera_mat=CAM_MAT,
        camera_fovy=45.0,
        eef_pos=np.array([-0.2, 0.0, 1.2]),
        gripper_qpos=np.array([0.04, -0.04]),
        gripper_qvel=np.zeros(2),
        finger_gap=np.full((len(SCENE.pickupable), 2), 0.01),
        gripper_command=-1.0,
        lin_vel=np.zeros((N, 3)),
        ang_vel=np.zeros((N, 3)),
        table_height=TABLE_Z,
    )
    for key, value in overrides.items():
        setattr(state, key, value)
    return state


def place(state: WorldState, name: str, xyz: tuple[float, float, float]) -> None:
    i = IDX[name]
    delta = np.asarray(xyz) - state.pos[i]
    state.pos[i] += delta
    state.aabb_lo[i] += delta
    state.aabb_hi[i] += delta


def touch(state: WorldState, a: int, b: int) -> None:
    state.contact[a, b] = state.contact[b, a] = True


def truths(state: WorldState, labeler: Labeler | None = None) -> set[str]:
    """True atoms of ``state``: a fresh labeler's first step, or the next step of ``labeler``."""
    labeler = labeler or Labeler(SCENE, GOAL)
    obj, act = labeler(state)
    vocab = labeler.vocabulary
    return {
        a
        for a, v in zip(vocab.object_atoms + vocab.action_atoms, np.concatenate([obj, act]), strict=False)
        if v
    }


def test_vocabulary_counts_and_order() -> None:
    vocab = build_vocabulary(SCENE)
    assert len(vocab.object_atoms) == 224 and len(vocab.action_atoms) == 12
    assert len(set(vocab.object_atoms)) == 224
    assert vocab.object_atoms[0] == "behind(bowl,bowl2)"
    assert vocab.object_atoms[42] == "in-front-of(bowl,bowl2)"
    assert vocab.object_atoms[168] == "on(bowl,bowl2)"
    assert vocab.object_atoms[-1] == "turned-on(stove)"
    assert vocab.action_atoms == (
        "grasped(bowl)", "grasped(bowl2)", "grasped(box)", "grasped(ramekin)", "grasped(plate)",
        "should-move-towards(bowl)", "should-move-towards(bowl2)", "should-move-towards(box)",
        "should-move-towards(ramekin)", "should-move-towards(plate)", "should-move-towards(cab)",
        "should-move-towards(stove)",
    )  # fmt: skip
    assert (
        "on(bowl,bowl)" not in vocab.object_atoms and "inside(cab,cab_top_region)" not in vocab.object_atoms
    )


def test_labels_follow_vocabulary_order() -> None:
    state = make_state()
    place(state, "bowl", (0.0, 0.3, TABLE_Z))
    labeler = Labeler(SCENE, GOAL)
    obj, _ = labeler(state)
    names = labeler.vocabulary.object_atoms
    # Every spatial bit must equal the matrix entry it names.
    x = image_x(state, 0.5 * (state.aabb_lo + state.aabb_hi))
    for k, name in enumerate(names[336:378]):  # the left-of block
        a, b = name[len("left-of(") : -1].split(",")
        assert obj[336 + k] == (x[IDX[a]] - x[IDX[b]] < -0.02), name


def test_left_right_follow_the_model_image() -> None:
    state = make_state()
    # World +y is image-right for the physical camera, so image-left in the (mirrored) model image.
    place(state, "bowl", (0.0, 0.2, TABLE_Z))
    place(state, "plate", (0.0, -0.2, TABLE_Z))
    t = truths(state)
    assert "left-of(bowl,plate)" in t and "right-of(plate,bowl)" in t
    assert "right-of(bowl,plate)" not in t and "left-of(plate,bowl)" not in t


def test_left_right_margin_leaves_aligned_objects_unrelated() -> None:
    state = make_state()
    place(state, "bowl", (0.0, 0.004, TABLE_Z))  # 4 mm apart: inside the 1%-of-width margin
    place(state, "plate", (0.0, 0.0, TABLE_Z))
    t = truths(state)
    assert (
        not {"left-of(bowl,plate)", "right-of(bowl,plate)", "left-of(plate,bowl)", "right-of(plate,bowl)"} & t
    )


def test_behind_and_in_front_use_depth_from_the_camera() -> None:
    state = make_state()
    place(state, "bowl", (-0.2, 0.0, TABLE_Z))  # farther from the camera (which sits at +x)
    place(state, "plate", (0.15, 0.0, TABLE_Z))
    t = truths(state)
    assert "behind(bowl,plate)" in t and "in-front-of(plate,bowl)" in t
    assert "in-front-of(bowl,plate)" not in t


def test_stacking_is_neither_behind_nor_in_front() -> None:
    state = make_state()
    place(state, "box", (0.0, 0.0, TABLE_Z))
    place(state, "bowl", (0.0, 0.0, TABLE_Z + 0.05))
    t = truths(state)
    assert not {"behind(bowl,box)", "in-front-of(bowl,box)", "behind(box,bowl)"} & t


def test_on_matches_libero_rule() -> None:
    state = make_state()
    place(state, "plate", (0.0, 0.0, TABLE_Z))
    place(state, "bowl", (0.02, 0.0, TABLE_Z + 0.01))
    assert "on(bowl,plate)" not in truths(state)  # no contact
    touch(state, IDX["bowl"], IDX["plate"])
    assert "on(bowl,plate)" in truths(state)
    place(state, "bowl", (0.031, 0.0, TABLE_Z + 0.01))  # 3.1 cm off centre: LIBERO says no
    assert "on(bowl,plate)" not in truths(state)
    place(state, "bowl", (0.0, 0.0, TABLE_Z - 0.001))  # below the plate's origin
    assert "on(bowl,plate)" not in truths(state)
    assert "on(plate,bowl)" in truths(state)  # the rule is LIBERO's, symmetric cases included


def test_on_fixture_surface() -> None:
    state = make_state()
    top = state.region_pos[3]
    place(state, "bowl", (top[0] + 0.05, top[1], top[2] + 0.01))
    assert "on(bowl,cab)" not in truths(state)  # over the top but not touching
    touch(state, IDX["bowl"], IDX["cab"])
    assert "on(bowl,cab)" in truths(state)
    place(state, "bowl", (top[0] + 0.13, top[1], top[2] + 0.01))  # beyond the region's 12 cm half depth
    assert "on(bowl,cab)" not in truths(state)
    cook = state.region_pos[4]
    place(state, "bowl", (cook[0], cook[1], cook[2] + 0.0025 - 0.004))  # within 5 mm below the surface
    touch(state, IDX["bowl"], IDX["stove"])
    assert "on(bowl,stove)" in truths(state)


def test_on_table_contact_held_and_fixtures() -> None:
    state = make_state()
    touch(state, IDX["bowl"], TABLE)
    t = truths(state)
    assert "on-table(bowl)" in t and "on-table(plate)" not in t
    assert "on-table(cab)" in t and "on-table(stove)" in t  # fixtures: base at the table top
    state.aabb_lo[IDX["stove"], 2] = TABLE_Z + 0.05
    assert "on-table(stove)" not in truths(state)
    # A bowl held while still touching the table is not resting on it.
    pinch(state, "bowl")
    t = truths(state)
    assert "grasped(bowl)" in t and "on-table(bowl)" not in t


def test_inside_matches_libero_in_box() -> None:
    state = make_state()
    site = state.region_pos[0]
    place(state, "bowl", tuple(site + np.array([0.0, 0.05, -0.05])))
    assert "inside(bowl,cab_top_region)" in truths(state)
    place(state, "bowl", tuple(site + np.array([0.0, 0.0, -0.105])))  # within the 1 cm slack below
    assert "inside(bowl,cab_top_region)" in truths(state)
    place(state, "bowl", tuple(site + np.array([0.0, 0.0, -0.115])))
    assert "inside(bowl,cab_top_region)" not in truths(state)
    place(state, "bowl", tuple(site + np.array([0.031, 0.0, 0.0])))  # outside the 3 cm half width
    assert "inside(bowl,cab_top_region)" not in truths(state)


def test_open_and_turned_on_thresholds() -> None:
    state = make_state(container_qpos=np.array([-0.15, -0.14, 0.0]), on_off_qpos=np.array([0.5]))
    t = truths(state)
    assert "open(cab_top_region)" in t
    assert "open(cab_middle_region)" not in t  # LIBERO: open strictly below -0.14
    assert "open(cab_bottom_region)" not in t
    assert "turned-on(stove)" in t
    state.on_off_qpos = np.array([0.499])
    assert "turned-on(stove)" not in truths(state)


def finger(state: WorldState, name: str, side: int, gap: float = 0.0) -> None:
    """Put finger ``side`` (0 left, 1 right) ``gap`` metres from ``name`` (<= 0: in contact)."""
    state.finger_gap[IDX[name], side] = gap
    state.contact[IDX[name], LEFT + side] = state.contact[LEFT + side, IDX[name]] = gap <= 0


def untouch(state: WorldState, a: int, b: int) -> None:
    state.contact[a, b] = state.contact[b, a] = False


def pinch(state: WorldState, name: str, opening: float = 0.0045) -> None:
    """Both fingers on ``name``, held ``opening`` apart (a bowl's wall: ~4.5 mm)."""
    state.gripper_qpos = np.array([opening / 2, -opening / 2])
    finger(state, name, 0)
    finger(state, name, 1)


def towards(t: set[str]) -> set[str]:
    return {a for a in t if a.startswith("should-move-towards")}


def test_grasped_is_the_physical_grasp_not_the_command() -> None:
    state = make_state(gripper_command=1.0, gripper_qpos=np.array([0.039, -0.039]))
    i = IDX["bowl"]
    # Commanded closed, the grip point at the rim, the fingers still wide open and touching nothing: not grasped.
    state.eef_pos = state.aabb_hi[i] + np.array([-0.01, -0.01, 0.005])
    assert "grasped(bowl)" not in truths(state)
    finger(state, "bowl", 0)  # one finger arrives first: not a grasp yet
    finger(state, "bowl", 1, gap=0.0002)  # the other 0.2 mm off the wall: not touching yet
    assert "grasped(bowl)" not in truths(state)
    finger(state, "bowl", 1)  # both fingers on it: grasped, whatever the command said
    state.gripper_command = -1.0
    assert "grasped(bowl)" in truths(state)
    state.gripper_qpos = np.array([0.0005, -0.0005])  # shut on nothing
    assert "grasped(bowl)" not in truths(state)


def test_grasped_holds_on_one_finger_and_ends_without_contact() -> None:
    """The rim flicker of a two-pad check: one finger slides off the wall; the grasp lasts while the other presses."""
    labeler = Labeler(SCENE, GOAL)
    state = make_state()
    pinch(state, "bowl")
    assert "grasped(bowl)" in truths(state, labeler)
    finger(state, "bowl", 1, gap=0.003)
    assert "grasped(bowl)" in truths(state, labeler)  # held: one finger keeps it
    assert "grasped(bowl)" not in truths(state)  # but one finger never starts a grasp
    finger(state, "bowl", 0, gap=0.0002)  # 0.2 mm off the wall, the fingers still: no finger touches it
    assert "grasped(bowl)" not in truths(state, labeler)
    finger(state, "bowl", 0)  # and touching it again with one finger does not make it held
    assert "grasped(bowl)" not in truths(state, labeler)


def test_grasped_lasts_through_a_slip_into_a_firmer_pinch() -> None:
    labeler = Labeler(SCENE, GOAL)
    state = make_state()
    pinch(state, "bowl", opening=0.009)
    assert "grasped(bowl)" in truths(state, labeler)
    # The bowl slides down between the fingers, which chase it (closing at 40 mm/s) 0.3-0.5 mm off its wall.
    finger(state, "bowl", 0, gap=0.0003)
    finger(state, "bowl", 1, gap=0.0005)
    state.gripper_qpos, state.gripper_qvel = np.array([0.003, -0.003]), np.array([-0.02, 0.02])
    assert "grasped(bowl)" in truths(state, labeler)
    pinch(state, "bowl")  # caught again
    state.gripper_qvel = np.zeros(2)
    assert "grasped(bowl)" in truths(state, labeler)
    finger(state, "bowl", 0, gap=0.0015)  # a slip the fingers do not catch within 1 mm: lost
    finger(state, "bowl", 1, gap=0.0015)
    state.gripper_qvel = np.array([-0.02, 0.02])
    assert "grasped(bowl)" not in truths(state, labeler)


def test_grasped_ends_when_the_fingers_open() -> None:
    labeler = Labeler(SCENE, GOAL)
    state = make_state()
    pinch(state, "bowl")
    state.gripper_qvel = np.array([0.0008, -0.0008])  # a held grip may drift by ~1 mm/s
    assert "grasped(bowl)" in truths(state, labeler)
    state.gripper_qvel = np.array([0.006, -0.006])  # opening at 12 mm/s, both fingers still on the wall
    assert "grasped(bowl)" not in truths(state, labeler)


def test_labeler_reset_forgets_the_held_object() -> None:
    labeler = Labeler(SCENE, GOAL)
    state = make_state()
    pinch(state, "bowl")
    truths(state, labeler)
    finger(state, "bowl", 1, gap=0.003)
    labeler.reset()
    assert "grasped(bowl)" not in truths(state, labeler)


def test_grasped_is_exclusive() -> None:
    labeler = Labeler(SCENE, GOAL)
    state = make_state()
    place(state, "box", (0.0, 0.0, TABLE_Z))
    place(state, "bowl", (0.0, 0.06, TABLE_Z))
    state.eef_pos = np.array([0.0, 0.02, TABLE_Z + 0.03])  # nearer the box's centre
    pinch(state, "box")
    pinch(state, "bowl")
    t = truths(state, labeler)
    assert "grasped(box)" in t and "grasped(bowl)" not in t
    state.eef_pos = np.array([0.0, 0.05, TABLE_Z + 0.03])  # now nearer the bowl: the held box stays grasped
    t = truths(state, labeler)
    assert "grasped(box)" in t and "grasped(bowl)" not in t


def test_should_move_towards_follows_the_task_phase() -> None:
    labeler = Labeler(SCENE, GOAL)
    state = make_state()
    touch(state, IDX["bowl"], TABLE)
    assert towards(truths(state, labeler)) == {"should-move-towards(bowl)"}
    pinch(state, "bowl")
    assert towards(truths(state, labeler)) == {"should-move-towards(plate)"}
    # Placed and released: nothing left to move towards.
    state = make_state()
    place(state, "plate", (0.0, 0.0, TABLE_Z))
    place(state, "bowl", (0.0, 0.0, TABLE_Z + 0.01))
    touch(state, IDX["bowl"], IDX["plate"])
    assert not towards(truths(state))


def release(state: WorldState) -> None:
    """Open the fingers off the bowl, which starts to fall."""
    finger(state, "bowl", 0, gap=0.003)
    finger(state, "bowl", 1, gap=0.003)
    untouch(state, IDX["bowl"], TABLE)
    state.gripper_qpos = np.array([0.01, -0.01])
    state.gripper_qvel = np.array([0.02, -0.02])
    state.lin_vel[IDX["bowl"]] = (0.0, 0.0, -0.3)


def test_the_place_target_stays_the_target_while_the_released_object_settles() -> None:
    plate, bowl = {"should-move-towards(plate)"}, {"should-move-towards(bowl)"}
    # Released over the plate's centre (the goal holds once it lands), or 4 cm off it (not on it, by LIBERO's rule).
    for offset, landed, rested in ((0.0, plate, set()), (0.04, plate, bowl)):
        labeler = Labeler(SCENE, GOAL)
        state = make_state()
        place(state, "plate", (0.0, 0.0, TABLE_Z))
        place(state, "bowl", (offset, 0.0, TABLE_Z + 0.03))
        pinch(state, "bowl")
        assert towards(truths(state, labeler)) == plate
        release(state)  # falling onto the plate, not touching it yet
        assert towards(truths(state, labeler)) == plate
        place(state, "bowl", (offset, 0.0, TABLE_Z + 0.01))
        touch(state, IDX["bowl"], IDX["plate"])
        state.lin_vel[IDX["bowl"]] = (0.0, 0.0, 0.005)  # landed, barely moving, but still rocking
        state.ang_vel[IDX["bowl"]] = (1.0, 0.0, 0.0)
        assert towards(truths(state, labeler)) == landed  # the goal holds for one step only: still the plate
        state.lin_vel[:] = 0.0
        state.ang_vel[:] = 0.0
        assert towards(truths(state, labeler)) == rested  # at rest: nothing, or the bowl again


def test_an_object_dropped_away_from_the_target_becomes_the_target_again_once_it_rests() -> None:
    labeler = Labeler(SCENE, GOAL)
    state = make_state()
    place(state, "plate", (0.0, 0.0, TABLE_Z))
    place(state, "bowl", (0.0, 0.2, TABLE_Z + 0.05))
    pinch(state, "bowl")
    seq = [towards(truths(state, labeler))]
    release(state)
    seq.append(towards(truths(state, labeler)))
    touch(state, IDX["bowl"], TABLE)  # lands on the table, still sliding at 3 cm/s
    state.lin_vel[IDX["bowl"]] = (0.03, 0.0, 0.0)
    seq.append(towards(truths(state, labeler)))
    state.lin_vel[IDX["bowl"]] = (0.005, 0.0, 0.0)  # at rest
    seq.append(towards(truths(state, labeler)))
    plate, bowl = {"should-move-towards(plate)"}, {"should-move-towards(bowl)"}
    assert seq == [plate, plate, plate, bowl]


def test_labeler_rejects_a_goal_outside_the_scene() -> None:
    with pytest.raises(ValueError, match="goal"):
        Labeler(SCENE, Goal(pick="cup", place="plate"))


def test_a_placed_bowl_that_bounces_does_not_get_the_plate_as_target_again() -> None:
    # The default run's t07_i02: on(bowl, plate) reads 1, 1, 0, 1 after the release (a bounce).
    labeler = Labeler(SCENE, GOAL)
    state = make_state()
    place(state, "plate", (0.0, 0.0, TABLE_Z))
    place(state, "bowl", (0.0, 0.0, TABLE_Z + 0.03))
    pinch(state, "bowl")
    seq = [towards(truths(state, labeler))]
    release(state)
    seq.append(towards(truths(state, labeler)))
    for lands in (True, True, False, True):
        place(state, "bowl", (0.0, 0.0, TABLE_Z + (0.01 if lands else 0.03)))
        (touch if lands else untouch)(state, IDX["bowl"], IDX["plate"])
        state.lin_vel[IDX["bowl"]] = (0.0, 0.0, 0.05 if lands else 0.1)  # still bouncing: not at rest
        seq.append(towards(truths(state, labeler)))
    state.lin_vel[:] = 0.0
    seq.append(towards(truths(state, labeler)))
    plate = {"should-move-towards(plate)"}
    assert seq == [plate, plate, plate, plate, plate, plate, set()]  # plate, then none once, never back
    # on for three steps in a row (the cognition's debounce) ends the directive even before the bowl rests,
    # and a bounce after that does not bring it back
    labeler = Labeler(SCENE, GOAL)
    state = make_state()
    place(state, "plate", (0.0, 0.0, TABLE_Z))
    place(state, "bowl", (0.0, 0.0, TABLE_Z + 0.03))
    pinch(state, "bowl")
    seq = [towards(truths(state, labeler))]
    release(state)
    for lands in (True, True, True, False, True):
        place(state, "bowl", (0.0, 0.0, TABLE_Z + (0.01 if lands else 0.03)))
        (touch if lands else untouch)(state, IDX["bowl"], IDX["plate"])
        state.lin_vel[IDX["bowl"]] = (0.0, 0.0, 0.05)
        seq.append(towards(truths(state, labeler)))
    assert seq == [plate, plate, plate, set(), set(), set()]


def test_receptacles_and_doors() -> None:
    """A receptacle (a basket's contain region, after the surfaces in the region arrays) takes ``inside`` like a
    drawer; a door (a fixture's own joint, after the drawers in ``container_qpos``) takes ``open``."""
    scene = dataclasses.replace(
        SCENE,
        receptacles=("plate_contain_region",),
        doors=("stove",),
        door_articulation=(Articulation(-1.3, below=True),),
        region_parent={**SCENE.region_parent, "plate_contain_region": "plate"},
    )
    vocab = build_vocabulary(scene)
    assert vocab.object_atoms[-9:-5] == (
        "inside(ramekin,plate_contain_region)",
        "inside(plate,cab_top_region)",
        "inside(plate,cab_middle_region)",
        "inside(plate,cab_bottom_region)",
    )  # not inside(plate,plate_contain_region): never inside its own region
    assert vocab.object_atoms[-3:-1] == ("open(cab_bottom_region)", "open(stove)")
    assert len(vocab.object_atoms) == len(build_vocabulary(SCENE).object_atoms) + 4 + 1
    base = make_state()
    basket = np.array([0.3, 0.0, 0.95])
    state = make_state(
        region_pos=np.vstack([base.region_pos, basket]),
        region_mat=np.stack([np.eye(3)] * 6),
        region_size=np.vstack([base.region_size, [0.1, 0.1, 0.05]]),
        container_qpos=np.array([0.0, 0.0, 0.0, -1.5]),
    )
    place(state, "box", tuple(basket))
    obj, _ = Labeler(scene, GOAL)(state)
    t = {a for a, v in zip(vocab.object_atoms, obj, strict=True) if v}
    assert "inside(box,plate_contain_region)" in t and "inside(bowl,plate_contain_region)" not in t
    assert "open(stove)" in t and "open(cab_top_region)" not in t
    state.container_qpos = np.array([0.0, 0.0, 0.0, -1.0])
    obj, _ = Labeler(scene, GOAL)(state)
    assert not obj[vocab.object_atoms.index("open(stove)")]
