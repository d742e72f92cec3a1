"""The real LIBERO-spatial env: typed scene, settled init states, and detectors against LIBERO and the image."""

from __future__ import annotations

import numpy as np
import pytest

from vlaprobe.configs.env import EnvConfig
from vlaprobe.envs.libero import LiberoTaskEnv, suite_tasks
from vlaprobe.envs.spatial_scene import SPATIAL_GOAL, SPATIAL_SCENE
from vlaprobe.errors import VlaprobeError

pytestmark = pytest.mark.libero

BOWL = "akita_black_bowl_1"
# What each task's instruction says about the bowl at its init state.
INIT_FACTS: dict[int, list[str]] = {
    0: [f"on-table({BOWL})"],
    1: [f"on-table({BOWL})"],
    2: [f"on-table({BOWL})"],
    3: [f"on({BOWL},cookies_1)"],
    4: [f"inside({BOWL},wooden_cabinet_1_top_region)", "open(wooden_cabinet_1_top_region)"],
    5: [f"on({BOWL},glazed_rim_porcelain_ramekin_1)"],
    6: [f"on-table({BOWL})"],
    7: [f"on({BOWL},flat_stove_1)"],
    8: [f"on-table({BOWL})"],
    9: [f"on({BOWL},wooden_cabinet_1)"],
}


def true_atoms(env: LiberoTaskEnv) -> set[str]:
    obj, act = env.labeler.as_dict(env.world_state())
    return {k for k, v in {**obj, **act}.items() if v}


def test_suite_lists_ten_tasks() -> None:
    tasks = suite_tasks("libero_spatial")
    assert [i for i, _ in tasks] == list(range(10))
    assert all(text.startswith("pick up the black bowl") for _, text in tasks)


def test_every_task_init_state_matches_its_instruction() -> None:
    for task, facts in INIT_FACTS.items():
        with LiberoTaskEnv(task, EnvConfig(render=False)) as env:
            # The simulator-free copy (benchmarks, tests, clients) is what the simulator gives, in every task.
            assert env.scene == SPATIAL_SCENE and env.goal == SPATIAL_GOAL
            assert env.scene.pickupable[0] == BOWL and env.goal.place == "plate_1"
            assert len(env.labeler.vocabulary.object_atoms) == 224
            assert len(env.labeler.vocabulary.action_atoms) == 12
            for init in (0, 7):
                env.reset(init)
                t = true_atoms(env)
                for fact in facts:
                    assert fact in t, (task, init, fact)
                assert not any(a.startswith("grasped") for a in t), (task, init)
                assert {a for a in t if a.startswith("should-move-towards")} == {
                    f"should-move-towards({BOWL})"
                }
                assert f"on({BOWL},plate_1)" not in t
                assert "turned-on(flat_stove_1)" not in t
            if task == 0:  # "between the plate and the ramekin": the plate in front, the ramekin behind
                assert (
                    f"in-front-of(plate_1,{BOWL})" in t
                    and f"behind(glazed_rim_porcelain_ramekin_1,{BOWL})" in t
                )


def _segment_columns(env: LiberoTaskEnv, size: int) -> dict[str, float]:
    """Mean column of each pickupable object's pixels in the model's image, from MuJoCo's segmentation."""
    import mujoco

    model, data = env.sim_env.sim.model._model, env.sim_env.sim.data._data
    renderer = mujoco.Renderer(model, size, size)
    renderer.update_scene(data, camera="agentview")
    rgb = renderer.render()  # rows top first: the raw observation flipped upside down
    raw = env.render()

    def diff(a: np.ndarray) -> float:
        return float(np.abs(rgb.astype(int) - a.astype(int)).mean())

    # Same view: far closer to the raw render flipped upside down than to any other flip of it.
    assert diff(raw[::-1]) < 0.5 * min(diff(raw), diff(raw[:, ::-1]), diff(raw[::-1, ::-1]))
    renderer.enable_segmentation_rendering()
    seg = renderer.render()[:, ::-1]  # the model's image is the raw render rotated 180°
    renderer.close()
    geom, objtype = seg[..., 0], seg[..., 1]
    root = model.body_rootid[model.geom_bodyid]
    cols = np.broadcast_to(np.arange(size)[None, :], (size, size))
    out = {}
    for name in env.scene.pickupable:
        body = model.body(env.sim_env.objects_dict[name].root_body).id
        mask = (objtype == mujoco.mjtObj.mjOBJ_GEOM) & (root[np.clip(geom, 0, model.ngeom - 1)] == body)
        if mask.sum() > 20:
            out[name] = float(cols[mask].mean())
    return out


@pytest.mark.parametrize("task", [0, 6])
def test_left_of_agrees_with_the_rendered_image(task: int) -> None:
    size = 256
    with LiberoTaskEnv(task, EnvConfig(image_size=size)) as env:
        env.reset(0)
        cols = _segment_columns(env, size)
        assert len(cols) >= 4
        t = true_atoms(env)
        checked = 0
        for a, ca in cols.items():
            for b, cb in cols.items():
                if a != b and ca < cb - 6:  # clearly further left in the image
                    assert f"left-of({a},{b})" in t and f"right-of({b},{a})" in t, (a, b, ca, cb)
                    checked += 1
        assert checked >= 3


def test_reset_and_step_errors_are_one_line() -> None:
    with LiberoTaskEnv(2, EnvConfig(render=False)) as env:
        with pytest.raises(VlaprobeError, match="init state 50 out of range"):
            env.reset(50)
        env.reset(0)
        with pytest.raises(VlaprobeError, match="7 values"):
            env.step(np.zeros(6))
    with pytest.raises(VlaprobeError, match="no libero_spatial task"):
        LiberoTaskEnv("make coffee", EnvConfig(render=False))


def test_task_by_instruction() -> None:
    text = suite_tasks()[5][1]
    with LiberoTaskEnv(text.upper(), EnvConfig(render=False)) as env:
        assert env.task_index == 5


def _libero_truths(env: LiberoTaskEnv) -> dict[str, bool]:
    """LIBERO's own On / In / Open / TurnOn, spelled as our atoms (a fixture's surfaces count as the fixture)."""
    scene = env.scene
    out: dict[str, bool] = {}
    for a in scene.pickupable:
        for b in scene.tabletop:
            if a == b:
                continue
            value = env.libero_predicate("On", a, b)
            for region in scene.surfaces:
                if scene.region_parent[region] == b:
                    value = value or env.libero_predicate("On", a, region)
            out[f"on({a},{b})"] = value
        for c in scene.containers:
            out[f"inside({a},{c})"] = env.libero_predicate("In", a, c)
    for c in scene.containers:
        out[f"open({c})"] = env.libero_predicate("Open", c)
    for k in scene.on_off:
        out[f"turned-on({k})"] = env.libero_predicate("TurnOn", k)
    return out


@pytest.mark.parametrize("task", [4, 9, 7])
def test_detectors_agree_with_libero_along_a_rollout(task: int) -> None:
    """on / inside / open / turned-on equal LIBERO's own predicates on every step of an expert rollout."""
    from vlaprobe.experts import ScriptedExpert

    with LiberoTaskEnv(task, EnvConfig(render=False)) as env:
        env.reset(1)
        expert = ScriptedExpert(env)
        expert.reset()
        changed: set[str] = set()
        first: dict[str, bool] | None = None
        done = False
        for step in range(300):
            obj, _ = env.labeler.as_dict(env.world_state())
            theirs = _libero_truths(env)
            ours = {name: bool(obj[name]) for name in theirs}
            assert ours == theirs, (step, {k for k in ours if ours[k] != theirs[k]})
            first = first or theirs
            changed |= {k for k in theirs if theirs[k] != first[k]}
            if done:
                break
            done = env.step(expert.act()).success
        # The rollout must move the bowl between supports, or the comparison proves little.
        assert "on(akita_black_bowl_1,plate_1)" in changed


def test_same_init_gives_the_same_trajectory() -> None:
    rng = np.random.default_rng(0)
    actions = np.concatenate([rng.uniform(-1, 1, (30, 6)), np.ones((30, 1))], axis=1)

    def rollout(env: LiberoTaskEnv) -> np.ndarray:
        env.reset(3)
        for a in actions:
            env.step(a)
        return env.world_state().pos.copy()

    with LiberoTaskEnv(1, EnvConfig(render=False)) as env:
        first = rollout(env)
        env.reset(9)
        env.step(actions[0])  # disturb solver and gripper state in between
        np.testing.assert_array_equal(rollout(env), first)


def bddl_scene_agrees_with_the_simulator(env: LiberoTaskEnv) -> None:
    """The BDDL-derived scene names what the built simulator holds: the same objects and fixtures, drawers whose
    sites sit on joints, surfaces and receptacles whose sites do not, the same region parents, doors with a joint,
    on-off fixtures with LIBERO's turn-on rule."""
    e, scene = env.sim_env, env.scene
    assert scene.pickupable == tuple(e.objects_dict)
    assert scene.fixtures == tuple(e.fixtures_dict)
    sites = e.object_sites_dict
    assert all(sites[c].joints for c in scene.containers)
    assert not any(sites[r].joints for r in scene.surfaces + scene.receptacles)
    assert {r: sites[r].parent_name for r in scene.regions} == scene.region_parent
    jointed = {sites[n].parent_name for n in sites if getattr(sites[n], "joints", None)}
    assert set(scene.doors) == {
        f
        for f in scene.fixtures
        if e.get_object(f).joints and f not in jointed and not hasattr(e.get_object(f), "turn_on")
    }
    assert set(scene.on_off) == {f for f in scene.fixtures if hasattr(e.get_object(f), "turn_on")}


def test_the_bddl_scene_is_the_simulators() -> None:
    for task in (4, 9):
        with LiberoTaskEnv(task, EnvConfig(render=False)) as env:
            bddl_scene_agrees_with_the_simulator(env)
