"""Recovery on real LIBERO: the expert re-grasps after a drop, re-plans after a displacement and picks a
knocked-off bowl up again; the atoms the perturbations hit turn false and true again."""

from __future__ import annotations

import numpy as np
import pytest
from tests.collection.fakes import FakePolicy

from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.rollout import EpisodeControl, ExpertDriver, run_episode
from vlaprobe.rollout.perturb import Perturber, PerturbSpec
from vlaprobe.symbols.vocabulary import atom

pytestmark = pytest.mark.libero


def test_expert_recovers_from_every_perturbation_on_a_sampled_layout() -> None:
    with LiberoTaskEnv(0, EnvConfig(image_size=64, inits="sampled")) as env:
        pick, place = env.goal.pick, env.goal.place
        grasp_col = env.labeler.vocabulary.action_atoms.index(atom("grasped", pick))
        goal_col = env.labeler.vocabulary.object_atoms.index(atom("on", pick, place))
        control = EpisodeControl()
        perturber = Perturber(PerturbSpec(drop=1, displace=1, knock_off=1), 11, env.scene, env.goal)
        grasped, goal, marks, success = [], [], [], []
        for r in run_episode(
            env,
            FakePolicy(PolicyConfig()),
            ExpertDriver(env, 11),
            init=2,
            max_steps=450,
            post_success_steps=10,
            control=control,
        ):
            grasped.append(bool(r.action_atoms[grasp_col]))
            goal.append(bool(r.object_atoms[goal_col]))
            success.append(r.success)
            marks.append(r.perturbation)
            perturber.observe(r.t, r.world, grasped[-1], r.success, control)
        rows = {p.kind: p.row for p in perturber.planned}
    assert set(rows) == {"drop", "displace", "knock_off"} and None not in rows.values()
    assert marks[rows["displace"]] == "move" and marks[rows["knock_off"]] == "move"
    assert marks[rows["drop"]] == "drop"
    assert success[-1] and goal[-1]  # recovered: the bowl ends on the plate
    g = np.array(grasped)
    assert not g[: rows["displace"]].any()  # displaced before the grasp
    dropped = rows["drop"] + int(np.argmax(~g[rows["drop"] :]))
    assert not g[dropped] and g[dropped:].any()  # grasped turns false, then true again (the re-grasp)
    knocked = np.array(goal[rows["knock_off"] :])
    assert goal[rows["knock_off"] - 1] and not knocked[0] and knocked[-1]  # the goal atom: true, false, true
