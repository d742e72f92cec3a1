"""Each skill on real LIBERO, one task each (fixed init state 0): the planned expert reaches LIBERO's own goal,
and each skill does what its goal asks along the way. The rim pick (LIBERO-spatial) is tested in
test_rim_pick.py."""

from __future__ import annotations

import numpy as np
import pytest

from vlaprobe.configs.env import EnvConfig, SuiteName
from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.experts import ScriptedExpert
from vlaprobe.experts.drawer import Drawer

pytestmark = pytest.mark.libero


def solve(suite: SuiteName, task: int, max_steps: int = 300) -> tuple[bool, int, list[str]]:
    """Run the expert from init state 0: (LIBERO's success, steps, the skills' phases seen)."""
    with LiberoTaskEnv(task, EnvConfig(suite=suite, render=False)) as env:
        obs = env.reset(0)
        expert = ScriptedExpert(env)
        phases, steps = [], 0
        while steps < max_steps and not obs.success:
            obs = env.step(expert.act())
            phases.append(expert.phase)
            steps += 1
        return obs.success, steps, phases


@pytest.mark.parametrize(
    ("suite", "task", "skill", "phase"),
    [
        ("libero_object", 0, "body_place", "lower"),  # the alphabet soup into the basket
        ("libero_goal", 7, "turn_on", "turn"),  # turn on the stove
        ("libero_goal", 5, "push", "push"),  # push the plate to the front of the stove
        ("libero_goal", 0, "open", "pull"),  # open the middle drawer
    ],
)
def test_the_skill_reaches_the_goal(suite: SuiteName, task: int, skill: str, phase: str) -> None:
    success, steps, phases = solve(suite, task)
    assert success, f"{suite} task {task} not solved in {steps} steps (last phase {phases[-1]})"
    assert phase in phases  # the skill's own phase ran: not a lucky initial state


def test_close_pushes_an_open_drawer_shut() -> None:
    region = "wooden_cabinet_1_middle_region"
    with LiberoTaskEnv(0, EnvConfig(suite="libero_goal", render=False)) as env:
        env.reset(0)
        joint = env.sim_env.object_sites_dict[region].joints[0]
        env.sim_env.sim.data.set_joint_qpos(joint, -0.16)  # fully open (LIBERO: open below -0.14)
        env.sim_env.sim.forward()
        k = env.scene.openable.index(region)
        assert env.libero_predicate("Open", region)
        drawer = Drawer(env, region, opening=False)
        steps = 0
        while steps < 200 and not drawer.done:
            env.step(drawer.act())
            steps += 1
        assert env.libero_predicate("Close", region), env.world_state().container_qpos[k]
        assert np.isfinite(env.world_state().container_qpos[k])
