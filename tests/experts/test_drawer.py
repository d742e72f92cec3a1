"""The drawer skill's way to the handle on real LIBERO: it passes over a bottle standing near its path
(LIBERO-90 task 29, init 3: the hand turning to face the drawer at the handle's height knocked the ketchup over)."""

from __future__ import annotations

import numpy as np
import pytest

from vlaprobe.configs.env import EnvConfig
from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.experts.drawer import Drawer


@pytest.mark.libero
def test_the_hand_passes_over_a_bottle_on_its_way_to_the_handle() -> None:
    with LiberoTaskEnv(29, EnvConfig(suite="libero_90", render=False)) as env:
        np.random.seed(29003)
        env.reset(3)
        ketchup = env.scene.tabletop.index("ketchup_1")
        top = float(env.world_state().aabb_hi[ketchup][2])
        skill = Drawer(env, "white_cabinet_1_top_region", opening=True)
        steps = 0
        while steps < 200 and skill.phase not in ("close", "done"):  # until the fingers are at the handle
            env.step(skill.act())
            steps += 1
        assert skill.phase in ("close", "done"), skill.phase
        assert (
            float(env.world_state().aabb_hi[ketchup][2]) > top - 0.01
        )  # still standing (lying: 11 cm lower)
