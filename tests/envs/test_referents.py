"""``--inits sampled-swap`` without the simulator: the instruction's referent on hand-made states, the region
permutation, and the sampler swap (restored after the reset)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from tests.envs.test_placements import PROBLEM, layout
from tests.symbols.test_detectors import make_state

from vlaprobe.envs.placements import layout_problems, swap_regions, swapped_samplers, table_placements
from vlaprobe.envs.referents import Reference, instruction_form, parse_reference, reference_problems
from vlaprobe.envs.spatial_scene import SPATIAL_GOAL, SPATIAL_SCENE
from vlaprobe.symbols import Labeler, WorldState

SPATIAL = {  # LIBERO-spatial's instructions, task by task
    0: ("pick up the black bowl between the plate and the ramekin and place it on the plate", "between", ("plate_1", "glazed_rim_porcelain_ramekin_1")),
    1: ("pick up the black bowl next to the ramekin and place it on the plate", "next_to", ("glazed_rim_porcelain_ramekin_1",)),
    2: ("pick up the black bowl from table center and place it on the plate", "center", ()),
    3: ("pick up the black bowl on the cookie box and place it on the plate", "on", ("cookies_1",)),
    4: ("pick up the black bowl in the top drawer of the wooden cabinet and place it on the plate", "in", ("wooden_cabinet_1_top_region",)),
    5: ("pick up the black bowl on the ramekin and place it on the plate", "on", ("glazed_rim_porcelain_ramekin_1",)),
    6: ("pick up the black bowl next to the cookie box and place it on the plate", "next_to", ("cookies_1",)),
    7: ("pick up the black bowl on the stove and place it on the plate", "on", ("flat_stove_1",)),
    8: ("pick up the black bowl next to the plate and place it on the plate", "next_to", ("plate_1",)),
    9: ("pick up the black bowl on the wooden cabinet and place it on the plate", "on", ("wooden_cabinet_1",)),
}  # fmt: skip
NAMES = SPATIAL_SCENE.tabletop
OBJECT_ATOMS = Labeler(SPATIAL_SCENE, SPATIAL_GOAL).vocabulary.object_atoms


def state_with(**xy: tuple[float, float]) -> WorldState:
    """The detectors' test state (7 tabletop entities, as LIBERO-spatial), objects moved to the given (x, y)."""
    s = make_state()
    for name, (x, y) in xy.items():
        s.pos[NAMES.index(name), :2] = (x, y)
    return s


def problems(ref: Reference, state: WorldState, bits: np.ndarray | None = None, **kw: object) -> list[str]:
    bits = np.zeros(len(OBJECT_ATOMS), bool) if bits is None else bits
    return reference_problems(ref, SPATIAL_GOAL, SPATIAL_SCENE, state, bits, OBJECT_ATOMS, **kw)  # type: ignore[arg-type]


def test_every_spatial_instruction_parses() -> None:
    for text, relation, anchors in SPATIAL.values():
        assert parse_reference(text, SPATIAL_GOAL, SPATIAL_SCENE) == Reference(relation, anchors)
        assert instruction_form(text, SPATIAL_GOAL.pick) == relation
    assert instruction_form("pick up the black bowl and place it on the plate", SPATIAL_GOAL.pick) is None
    assert (
        parse_reference("pick up the black bowl next to the lamp and place it", SPATIAL_GOAL, SPATIAL_SCENE)
        is None
    )


def test_next_to_singles_out_the_pick_or_says_why_not() -> None:
    ref = Reference("next_to", ("glazed_rim_porcelain_ramekin_1",))
    ramekin = (0.0, 0.2)
    ok = state_with(
        glazed_rim_porcelain_ramekin_1=ramekin, akita_black_bowl_1=(0.1, 0.2), akita_black_bowl_2=(0.3, 0.2)
    )
    assert problems(ref, ok) == []
    both = state_with(
        glazed_rim_porcelain_ramekin_1=ramekin, akita_black_bowl_1=(0.1, 0.2), akita_black_bowl_2=(-0.12, 0.2)
    )
    assert problems(ref, both) == [
        "the instruction (next to glazed_rim_porcelain_ramekin_1) also fits akita_black_bowl_2"
    ]
    far = state_with(
        glazed_rim_porcelain_ramekin_1=ramekin, akita_black_bowl_1=(0.2, 0.2), akita_black_bowl_2=(-0.1, 0.2)
    )
    assert problems(ref, far) == [
        "the instruction (next to glazed_rim_porcelain_ramekin_1) no longer fits akita_black_bowl_1",
        "the instruction (next to glazed_rim_porcelain_ramekin_1) also fits akita_black_bowl_2",
    ]


def test_between_and_center() -> None:
    between = Reference("between", ("plate_1", "glazed_rim_porcelain_ramekin_1"))
    ends = {"plate_1": (0.0, 0.2), "glazed_rim_porcelain_ramekin_1": (0.0, -0.2)}
    assert (
        problems(between, state_with(**ends, akita_black_bowl_1=(0.02, 0.0), akita_black_bowl_2=(0.2, 0.0)))
        == []
    )
    assert problems(
        between, state_with(**ends, akita_black_bowl_1=(0.02, 0.0), akita_black_bowl_2=(-0.03, 0.1))
    ) == ["the instruction (between plate_1 and glazed_rim_porcelain_ramekin_1) also fits akita_black_bowl_2"]
    assert (
        "no longer fits akita_black_bowl_1"
        in problems(
            between, state_with(**ends, akita_black_bowl_1=(0.0, 0.19), akita_black_bowl_2=(0.3, 0.0))
        )[0]
    )  # next to the plate, at the segment's end: not between
    center = Reference("center", ())
    mid = np.array([-0.1, 0.0])
    assert (
        problems(
            center, state_with(akita_black_bowl_1=(-0.09, 0.0), akita_black_bowl_2=(0.1, 0.3)), center=mid
        )
        == []
    )
    assert problems(
        center, state_with(akita_black_bowl_1=(0.1, 0.3), akita_black_bowl_2=(-0.09, 0.0)), center=mid
    ) == [
        "the instruction (center) no longer fits akita_black_bowl_1",
        "the instruction (center) also fits akita_black_bowl_2",
    ]
    assert "do not give" in problems(center, state_with())[0]


def test_on_and_in_read_the_detectors_atoms() -> None:
    ref = Reference("on", ("cookies_1",))
    bits = np.zeros(len(OBJECT_ATOMS), bool)
    bits[OBJECT_ATOMS.index("on(akita_black_bowl_1,cookies_1)")] = True
    assert problems(ref, state_with(), bits) == []
    bits[OBJECT_ATOMS.index("on(akita_black_bowl_2,cookies_1)")] = True
    assert problems(ref, state_with(), bits) == [
        "the instruction (on cookies_1) also fits akita_black_bowl_2"
    ]
    drawer = Reference("in", ("wooden_cabinet_1_top_region",))
    assert problems(drawer, state_with()) == [
        "the instruction (in wooden_cabinet_1_top_region) no longer fits akita_black_bowl_1"
    ]


SWAP_PROBLEM = {
    "regions": {f"main_table_{r}_region": {"target": "main_table", "ranges": [[i, 0.0, i + 0.02, 0.02]]} for i, r in enumerate("abc")},
    "objects": {"bowl": ["bowl_1", "bowl_2"], "plate": ["plate_1"], "box": ["box_1"]},
    "fixtures": {"table": ["main_table"]},
    "initial_state": [
        ["on", "bowl_1", "main_table_a_region"],
        ["on", "bowl_2", "main_table_b_region"],
        ["on", "plate_1", "main_table_c_region"],
        ["on", "box_1", "bowl_2"],
    ],
}  # fmt: skip


def test_region_permutation_is_seeded_and_covers_the_table_placed_objects() -> None:
    placed = table_placements(SWAP_PROBLEM)
    assert placed == {
        "bowl_1": "main_table_a_region",
        "bowl_2": "main_table_b_region",
        "plate_1": "main_table_c_region",
    }
    draws = [swap_regions(SWAP_PROBLEM, np.random.default_rng(seed)) for seed in range(20)]
    assert all(sorted(d) == sorted(placed) and sorted(d.values()) == sorted(placed.values()) for d in draws)
    assert swap_regions(SWAP_PROBLEM, np.random.default_rng(3)) == draws[3]
    assert len({tuple(sorted(d.items())) for d in draws}) > 1  # not always the same permutation


def test_swapped_samplers_take_the_other_regions_ranges_and_restore_them() -> None:
    samplers = {
        n: SimpleNamespace(x_ranges=[(i, i + 1)], y_ranges=[(-i, 1 - i)])
        for i, n in enumerate(("bowl_1", "bowl_2", "plate_1"))
    }
    env = SimpleNamespace(
        placement_initializer=SimpleNamespace(samplers=samplers), parsed_problem=SWAP_PROBLEM
    )
    swap = {
        "bowl_1": "main_table_c_region",
        "plate_1": "main_table_a_region",
        "bowl_2": "main_table_b_region",
    }
    with swapped_samplers(env, swap):
        assert samplers["bowl_1"].x_ranges == [(2, 3)] and samplers["plate_1"].y_ranges == [(0, 1)]
        assert samplers["bowl_2"].x_ranges == [(1, 2)]
    assert samplers["bowl_1"].x_ranges == [(0, 1)] and samplers["plate_1"].y_ranges == [(-2, -1)]
    with pytest.raises(RuntimeError), swapped_samplers(env, swap):
        raise RuntimeError("a failed reset")
    assert samplers["bowl_1"].x_ranges == [(0, 1)]  # restored after an exception too


def test_layout_check_follows_the_swapped_region() -> None:
    problem = {
        **PROBLEM,
        "regions": {
            **PROBLEM["regions"],
            "main_table_b_region": {"target": "main_table", "ranges": [[0.3, 0.3, 0.32, 0.32]]},
        },
    }
    at_b = layout(pos=np.array([[0.31, 0.31, 0.92], [0.31, 0.31, 0.95]]))
    assert layout_problems(at_b, problem, {}) == ["bowl_1 left its region main_table_a_region"]
    assert layout_problems(at_b, problem, {}, {"bowl_1": "main_table_b_region"}) == []


def test_permutations_are_redrawn_until_the_region_centres_keep_the_referent() -> None:
    from vlaprobe.envs.placements import region_centers
    from vlaprobe.envs.referents import placement_problems
    from vlaprobe.symbols import Goal, Scene

    scene = Scene(("bowl_1", "bowl_2", "plate_1", "box_1"), (), (), ())
    goal = Goal(pick="bowl_1", place="plate_1")
    ref = Reference("next_to", ("plate_1",))
    offset = np.array([1.0, 0.0, 0.9])
    centres = region_centers(SWAP_PROBLEM, table_placements(SWAP_PROBLEM), offset)
    # Regions a, b, c are 1 m apart along x; box_1 stands on bowl_2, so it is where bowl_2 is.
    assert {n: tuple(v) for n, v in centres.items()} == {
        "bowl_1": (1.01, 0.01), "bowl_2": (2.01, 0.01), "plate_1": (3.01, 0.01), "box_1": (2.01, 0.01)
    }  # fmt: skip

    def accept(swap: object) -> bool:
        xy = region_centers(SWAP_PROBLEM, swap, offset)  # type: ignore[arg-type]
        return not placement_problems(ref, goal, scene, xy, None)

    for seed in range(10):  # 1 m apart, nothing is next to anything: never accepted -> the BDDL's own regions
        assert swap_regions(SWAP_PROBLEM, np.random.default_rng(seed), accept, tries=20) == table_placements(
            SWAP_PROBLEM
        )
    near = {"bowl_1": (0.0, 0.0), "plate_1": (0.1, 0.0), "bowl_2": (0.5, 0.0)}
    assert placement_problems(ref, goal, scene, {k: np.array(v) for k, v in near.items()}, None) == []
    unknown = {"bowl_1": (0.0, 0.0), "bowl_2": (0.5, 0.0)}  # the anchor's place unknown: not judged
    assert placement_problems(ref, goal, scene, {k: np.array(v) for k, v in unknown.items()}, None) == []
