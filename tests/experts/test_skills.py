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


def test_the_push_starts_deeper_inside_the_rim_when_the_hand_sits_on_a_handle() -> None:
    """LIBERO-goal task 5, init 3: the plate stands close to the cabinet; the first descent inside its rim sits on
    a drawer's handle, the next starts deeper and pushes the plate to the front of the stove."""
    with LiberoTaskEnv(5, EnvConfig(suite="libero_goal", render=False)) as env:
        obs = env.reset(3)
        expert = ScriptedExpert(env)
        steps = 0
        while steps < 300 and not obs.success:
            obs = env.step(expert.act())
            steps += 1
        assert obs.success, f"not solved in {steps} steps (phase {expert.phase})"
        assert expert.skills[0]._deeper > 0.0  # a blocked descent moved the start inside the rim


def test_the_wrist_turns_the_way_its_range_allows() -> None:
    """Of the two finger directions that grip alike, the hand takes the one its last joint can reach (a world
    turn by +a turns that joint by -a)."""
    with LiberoTaskEnv(0, EnvConfig(suite="libero_goal", render=False)) as env:
        env.reset(0)
        skill = Drawer(env, "wooden_cabinet_1_middle_region")
        data, model = env.sim_env.sim.data._data, env.sim_env.sim.model._model
        data.qpos[skill._wrist.qposadr[0]] = model.jnt_range[skill._wrist.id][1] - 0.2  # near its upper limit
        env.sim_env.sim.forward()
        current = skill._current_finger_axis()

        def turned(angle: float) -> np.ndarray:  # the finger axis turned by ``angle`` about the vertical
            c, s = np.cos(angle), np.sin(angle)
            return np.array([c * current[0] - s * current[1], s * current[0] + c * current[1], 0.0])

        assert np.allclose(
            skill._wrist_axis(turned(0.4)), turned(0.4)
        )  # the joint turns down: the small turn
        assert np.allclose(skill._wrist_axis(turned(-0.4)), -turned(-0.4))  # up past its limit: the other way
