"""``--perturb`` on real LIBERO beyond one conjunct: a LIBERO-10 goal of two conjuncts (both cans into the basket)
is perturbed on the can placed last, every kind, and the expert recovers; a drawer's way, read from the
simulator, covers the cabinet and the area its drawers open over (where moved objects may not land)."""

from __future__ import annotations

import numpy as np
import pytest
from tests.collection.fakes import FakePolicy

from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.envs.libero_world import HAND_MARGIN
from vlaprobe.rollout import EpisodeControl, ExpertDriver, run_episode
from vlaprobe.rollout.perturb import KINDS, Perturber, PerturbSpec, perturb_target
from vlaprobe.symbols import Goal
from vlaprobe.symbols.vocabulary import atom

pytestmark = pytest.mark.libero


def test_a_drawers_way_is_its_cabinet_swept_along_the_opening_by_its_travel_and_a_hand() -> None:
    with LiberoTaskEnv(3, EnvConfig(suite="libero_goal", image_size=64, inits="sampled")) as env:
        env.reset(0)
        world = env.world_state()
        (lo, hi), *rest = env.drawer_fronts()
        cabinet = env.scene.tabletop.index("wooden_cabinet_1")
        sim = env.sim_env.sim
        joint = sim.model.joint_name2id(
            env.sim_env.object_sites_dict["wooden_cabinet_1_top_region"].joints[0]
        )
        sim.data.qpos[sim.model.jnt_qposadr[joint]] = -0.15  # the top drawer open (LIBERO's threshold -0.14)
        sim.forward()
        opened = env.world_state()
        (opened_lo, opened_hi), *_ = env.drawer_fronts()
        o_c_lo, o_c_hi = opened.aabb_lo[cabinet, :2], opened.aabb_hi[cabinet, :2]
    assert not rest  # one cabinet, three drawers: one way
    c_lo, c_hi = world.aabb_lo[cabinet, :2], world.aabb_hi[cabinet, :2]
    assert np.all(lo <= c_lo) and np.all(hi >= c_hi)
    grown = (hi - lo) - (c_hi - c_lo)  # LIBERO's cabinet faces the table's middle: its drawers slide 16 cm
    assert np.isclose(np.max(grown), 0.16 + HAND_MARGIN) and np.isclose(np.min(grown), 0.0)
    assert np.allclose(lo, opened_lo, atol=0.005) and np.allclose(hi, opened_hi, atol=0.005)
    # with a drawer open, the cabinet's box holds it: the way is the same, not swept by the whole travel again
    assert np.max(o_c_hi - o_c_lo - (c_hi - c_lo)) > 0.1


@pytest.mark.heavy
def test_expert_recovers_from_every_perturbation_of_the_can_placed_last() -> None:
    with LiberoTaskEnv(0, EnvConfig(suite="libero_10", image_size=64, inits="sampled", max_steps=600)) as env:
        goal = perturb_target(env)
        assert env.perturb_goal is None and goal == Goal("tomato_sauce_1", "basket_1")
        grasp_col = env.labeler.vocabulary.action_atoms.index(atom("grasped", goal.pick))
        control = EpisodeControl()
        spec = PerturbSpec(**{k: 1.0 for k in KINDS})
        perturber = Perturber(spec, 1, env.scene, goal, env.robot_base, max_steps=600)
        grasped, marks, success = [], [], []
        for r in run_episode(
            env,
            FakePolicy(PolicyConfig()),
            ExpertDriver(env, 1),
            init=1,
            max_steps=600,
            post_success_steps=0,
            control=control,
        ):
            grasped.append(bool(r.action_atoms[grasp_col]))
            success.append(r.success)
            marks.append(r.perturbation)
            perturber.observe(r.t, r.world, grasped[-1], r.success, control)
    rows = {p.kind: p.row for p in perturber.planned}
    assert set(rows) == set(KINDS) and None not in rows.values()  # every kind came
    assert marks[rows["displace"]] == "move" and marks[rows["drop"]] == "drop"
    assert not any(grasped[: rows["displace"]])  # displaced before anything of it was grasped
    assert success[rows["knock_off"] - 1] and not success[rows["knock_off"]]  # the goal held, then was undone
    assert success[-1]  # both cans in the basket again
