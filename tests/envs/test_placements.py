"""Sampled placements: the BDDL check, the settled-layout check on hand-made layouts, seeds, and (real LIBERO)
reproducible, checked sampled resets."""

from __future__ import annotations

import numpy as np
import pytest

from vlaprobe.envs.placements import (
    PENETRATION,
    SettledLayout,
    layout_problems,
    placement_seed,
    sampling_problems,
)

PROBLEM = {
    "regions": {
        "main_table_a_region": {"target": "main_table", "ranges": [[0.0, 0.0, 0.02, 0.02]]},
        "cabinet_top_region": {"target": "cabinet", "ranges": []},
    },
    "objects": {"bowl": ["bowl_1", "bowl_2"], "plate": ["plate_1"]},
    "fixtures": {"table": ["main_table"], "cabinet": ["cabinet"]},
    "initial_state": [
        ["on", "bowl_1", "main_table_a_region"],
        ["in", "bowl_2", "cabinet_top_region"],
        ["on", "plate_1", "bowl_1"],
    ],
}
UPRIGHT = np.array([1.0, 0.0, 0.0, 0.0])


def layout(**changes: object) -> SettledLayout:
    base = dict(
        names=("bowl_1", "plate_1"),
        pos=np.array([[0.01, 0.01, 0.92], [0.01, 0.01, 0.95]]),
        quat_sampled=np.stack([UPRIGHT, UPRIGHT]),
        quat_settled=np.stack([UPRIGHT, UPRIGHT]),
        speed=np.zeros(2),
        penetration={("bowl_1", "plate_1"): 0.001},
        table_height=0.9,
        workspace_offset=np.array([0.0, 0.0, 0.9]),
    )
    base.update(changes)
    return SettledLayout(**base)  # type: ignore[arg-type]


def test_every_spatial_like_problem_can_be_sampled_and_gaps_are_named() -> None:
    assert sampling_problems(PROBLEM) == []
    broken = {**PROBLEM, "initial_state": PROBLEM["initial_state"][1:]}
    assert sampling_problems(broken) == ["bowl_1 has no On/In condition in (:init)"]
    nowhere = {**PROBLEM, "initial_state": [*PROBLEM["initial_state"][1:], ["on", "bowl_1", "moon"]]}
    assert sampling_problems(nowhere) == ["bowl_1 is placed on moon, which is neither a region nor an object"]
    unranged = {
        **PROBLEM,
        "regions": {**PROBLEM["regions"], "main_table_a_region": {"target": "main_table", "ranges": []}},
    }
    assert sampling_problems(unranged) == ["bowl_1's region main_table_a_region has no sampling ranges"]


def test_a_clean_layout_passes_and_each_fault_is_named() -> None:
    ok = {"in bowl_2 cabinet_top_region": True, "on plate_1 bowl_1": True}
    assert layout_problems(layout(), PROBLEM, ok) == []
    fell = layout(pos=np.array([[0.01, 0.01, 0.80], [0.01, 0.01, 0.95]]))
    assert layout_problems(fell, PROBLEM, ok) == ["bowl_1 fell off the table"]
    half_turn = np.array([np.cos(0.3), np.sin(0.3), 0.0, 0.0])  # 0.6 rad about x
    tipped = layout(quat_settled=np.stack([UPRIGHT, half_turn]))
    assert layout_problems(tipped, PROBLEM, ok) == ["plate_1 tipped over (34 deg)"]
    spun = np.array([np.cos(0.5), 0.0, 0.0, np.sin(0.5)])  # 1 rad (57 deg) about the vertical axis: upright
    assert layout_problems(layout(quat_settled=np.stack([UPRIGHT, spun])), PROBLEM, ok) == []
    spun_then_tipped = np.array(
        [
            np.cos(0.5) * np.cos(0.3),
            np.cos(0.5) * np.sin(0.3),
            np.sin(0.5) * np.sin(0.3),
            np.sin(0.5) * np.cos(0.3),
        ]
    )
    assert layout_problems(layout(quat_settled=np.stack([UPRIGHT, spun_then_tipped])), PROBLEM, ok) == [
        "plate_1 tipped over (34 deg)"
    ]
    assert layout_problems(layout(speed=np.array([0.0, 0.2])), PROBLEM, ok) == [
        "plate_1 still moving (0.20 m/s)"
    ]
    away = layout(
        pos=np.array([[0.08, 0.01, 0.92], [0.08, 0.01, 0.95]])
    )  # 6 cm beyond the range, 1 cm beyond the slack
    assert layout_problems(away, PROBLEM, ok) == ["bowl_1 left its region main_table_a_region"]
    deep = layout(penetration={("bowl_1", "plate_1"): PENETRATION + 0.002})
    assert layout_problems(deep, PROBLEM, ok) == ["bowl_1 and plate_1 intersect (7 mm)"]
    assert layout_problems(layout(), PROBLEM, {**ok, "on plate_1 bowl_1": False}) == [
        "(on plate_1 bowl_1) does not hold"
    ]


def test_placement_seeds_are_fixed_by_suite_task_seed_index_and_draw() -> None:
    assert placement_seed("libero_spatial", 3, 0, 7, 0) == placement_seed("libero_spatial", 3, 0, 7, 0)
    seeds = {
        placement_seed(suite, t, seed, i, d)
        for suite in ("libero_spatial", "libero_object")
        for t in range(3)
        for seed in (11, 12)
        for i in range(10)
        for d in range(3)
    }
    assert len(seeds) == 2 * 3 * 2 * 10 * 3 and all(0 <= s < 2**31 for s in seeds)


@pytest.mark.libero
def test_sampled_resets_reproduce_differ_and_pass_their_checks() -> None:
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.envs.libero import LiberoTaskEnv, task_problem

    with LiberoTaskEnv(3, EnvConfig(render=False, inits="sampled")) as env:  # bowl on the cookie box
        assert env.num_init_states == 1000 and sampling_problems(task_problem(3)) == []
        env.reset(5)
        first, report = env.world_state().pos.copy(), env.last_placement
        env.reset(6)
        other = env.world_state().pos.copy()
        env.reset(5)
        again = env.world_state().pos
        assert report is not None and report.index == 5 and report.draws == 1 + len(report.rejected)
        assert report.seed == placement_seed("libero_spatial", 3, 0, 5, report.draws - 1)
        np.testing.assert_allclose(again, first, atol=1e-6)
        assert np.abs(other - first).max() > 1e-3  # another layout
        assert "on(akita_black_bowl_1,cookies_1)" in {
            k for k, v in env.labeler.as_dict(env.world_state())[0].items() if v
        }


@pytest.mark.libero
def test_place_object_moves_a_movable_object_onto_the_table() -> None:
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.envs.libero import LiberoTaskEnv
    from vlaprobe.errors import VlaprobeError

    with LiberoTaskEnv(0, EnvConfig(image_size=32)) as env:
        env.reset(0)
        obs = env.place_object("akita_black_bowl_1", (-0.1, 0.0))
        state = env.world_state()
        i = env.scene.tabletop.index("akita_black_bowl_1")
        np.testing.assert_allclose(state.pos[i, :2], (-0.1, 0.0), atol=1e-6)
        assert abs(state.aabb_lo[i, 2] - state.table_height - 0.003) < 1e-3 and obs.image is not None
        for _ in range(10):
            env.step(np.array([0, 0, 0, 0, 0, 0, -1.0]))
        assert "on-table(akita_black_bowl_1)" in {
            k for k, v in env.labeler.as_dict(env.world_state())[0].items() if v
        }
        with pytest.raises(VlaprobeError, match="not a movable object"):
            env.place_object("wooden_cabinet_1", (0.0, 0.0))


@pytest.mark.libero
def test_swapped_regions_keep_the_instruction_and_the_expert_solves_them() -> None:
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.envs.libero import LiberoTaskEnv
    from vlaprobe.envs.referents import parse_reference, reference_problems
    from vlaprobe.experts import ScriptedExpert

    # Task 1, "... the black bowl next to the ramekin ...": sample 0 (seed 0) starts the bowl in the ramekin's
    # region, the ramekin in the region next to it and the plate next to the box (a layout LIBERO never makes).
    with LiberoTaskEnv(1, EnvConfig(render=False, inits="sampled-swap")) as env:
        obs = env.reset(0)
        report = env.last_placement
        assert (
            report is not None and dict(report.regions)["akita_black_bowl_1"] == "main_table_ramekin_region"
        )
        state = env.world_state()
        first = state.pos.copy()
        ref = parse_reference(env.instruction, env.goal, env.scene)
        assert ref is not None and ref.relation == "next_to"
        bits, _ = env.labeler(state)
        names = env.labeler.vocabulary.object_atoms
        assert reference_problems(ref, env.goal, env.scene, state, bits, names) == []
        env.labeler.reset()
        expert = ScriptedExpert(env)
        for _ in range(300):
            if obs.success:
                break
            obs = env.step(expert.act())
        assert obs.success  # the expert reads the goal's bowl wherever it starts
        env.reset(0)
        np.testing.assert_allclose(env.world_state().pos, first, atol=1e-6)  # the key reproduces the layout
