"""The arm's links in the rim grasp's side choice: the decision on hand-made scores, and the arm's predicted
clearance on real LIBERO (LIBERO-90 task 29, init 3: the bowl stands 1.7 cm in front of the open drawer's handle)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from vlaprobe.configs.env import EnvConfig
from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.experts.arm import ArmModel
from vlaprobe.experts.geometry import GRASP_DEPTHS, GRIP_INSET, _down_rotation
from vlaprobe.experts.rim_pick import RimPickPlace

BOWL_LO, BOWL_HI = np.array([-0.05, -0.05, 0.9]), np.array([0.05, 0.05, 0.95])


def planner(arm_penalty, calls: list | None = None) -> RimPickPlace:  # type: ignore[no-untyped-def]
    """A rim pick without a simulator: no obstacles around the bowl, the robot's base far towards -x, a small
    gripper, and ``arm_penalty(grip, finger_axis)`` standing for the arm's links."""
    skill = RimPickPlace.__new__(RimPickPlace)
    skill.rng = np.random.default_rng(0)
    skill._blocked = []
    skill._data = SimpleNamespace(xpos=np.array([[-0.66, 0.0, 0.9]]))
    skill._robot_base = 0
    skill._current_finger_axis = lambda: np.array([1.0, 0.0, 0.0])  # type: ignore[method-assign]
    skill._wrist_axis = lambda axis: axis  # type: ignore[method-assign]
    corners = np.array([[x, y, z] for x in (-0.01, 0.01) for y in (-0.01, 0.01) for z in (-0.01, 0.01)])
    skill._gripper_points = lambda: corners  # type: ignore[method-assign]
    skill._obstacle_boxes = lambda: (np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)))  # type: ignore[method-assign]

    def penalty(grip: np.ndarray, axis: np.ndarray) -> float:
        if calls is not None:
            calls.append(grip)
        return float(arm_penalty(grip, axis))

    skill._arm_penalty = penalty  # type: ignore[method-assign]
    return skill


def test_a_side_whose_forearm_meets_an_obstacle_loses() -> None:
    # Free around the bowl, the side nearest the robot wins (shorter reach)...
    free = planner(lambda grip, axis: 0.0)
    free._choose_side(BOWL_LO, BOWL_HI)
    assert free._side is not None and free._side[0] < -0.5
    # ... unless the arm's links would meet something there (a drawer's front above the bowl's -x half).
    skill = planner(lambda grip, axis: 0.03 if grip[0] < 0.0 else 0.0)
    skill._choose_side(BOWL_LO, BOWL_HI)
    assert skill._side is not None and skill._side[0] >= 0.0


def test_a_shallower_grasp_wins_when_it_lifts_the_forearm_clear() -> None:
    rim = BOWL_HI[2]
    # The arm comes 1 cm too near at the deepest grasp, clear 1 cm higher up.
    skill = planner(lambda grip, axis: max(0.0, 0.01 - (grip[2] - (rim - GRASP_DEPTHS[0]))))
    skill._choose_side(BOWL_LO, BOWL_HI)
    assert skill._depth == GRASP_DEPTHS[-1]
    free = planner(lambda grip, axis: 0.0)
    free._choose_side(BOWL_LO, BOWL_HI)
    assert free._depth == GRASP_DEPTHS[0]


def test_the_arm_is_checked_only_while_a_candidate_can_still_win() -> None:
    calls: list = []
    skill = planner(lambda grip, axis: 0.0, calls)
    skill._choose_side(BOWL_LO, BOWL_HI)
    assert len(calls) == 1  # the best candidate's arm is clear: nothing else can beat it


@pytest.mark.libero
def test_the_forearm_meets_the_open_drawer_from_the_robots_side() -> None:
    with LiberoTaskEnv(29, EnvConfig(suite="libero_90", render=False)) as env:
        np.random.seed(29003)
        env.reset(3)
        skill = RimPickPlace.__new__(RimPickPlace)
        robot = env.sim_env.robots[0]
        model = env.sim_env.sim.model._model
        site = int(robot.eef_site_id)
        gripper = np.array([model.geom(g).id for g in robot.gripper.contact_geoms])
        arm = ArmModel(env, site, gripper)
        assert [model.geom(int(g)).name for g in arm.geoms] == [
            "robot0_link4_collision",
            "robot0_link5_collision",
            "robot0_link6_collision",
        ]
        state = env.world_state()
        bowl = env.scene.tabletop.index("akita_black_bowl_1")
        lo, hi = state.aabb_lo[bowl], state.aabb_hi[bowl]
        centre, radius = skill._rim(lo, hi)
        cabinet = [g for g in range(model.ngeom) if model.geom(g).name.startswith("white_cabinet_1_g")]
        obstacles = np.array([g for g in cabinet if model.geom_contype[g] or model.geom_conaffinity[g]])

        def clearance(side: np.ndarray, depth: float) -> float:
            grip = centre + (radius - GRIP_INSET) * side
            grip[2] = hi[2] - depth
            return arm.clearance(grip, _down_rotation(side), obstacles, 0.1)

        robot_side, away = np.array([-1.0, 0.0, 0.0]), np.array([0.0, -1.0, 0.0])
        # Measured from the settled init state: -0.9 / -0.7 cm from the robot's side (deep / shallow grasp),
        # +2.2 / +2.6 cm from the side away from the cabinet.
        assert clearance(robot_side, GRASP_DEPTHS[0]) < 0.0  # the forearm in the drawer's front
        assert clearance(robot_side, GRASP_DEPTHS[-1]) < 0.0
        assert clearance(away, GRASP_DEPTHS[-1]) > clearance(away, GRASP_DEPTHS[0]) > 0.015
        # The prediction puts the grip site where asked.
        target = centre + np.array([0.0, 0.0, 0.05])
        arm.solve(target, _down_rotation(np.array([1.0, 0.0, 0.0])))
        assert np.linalg.norm(arm._scratch.site_xpos[site] - target) < 0.005
