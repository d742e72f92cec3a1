"""Clearing the way of a drawer: the move on hand-made boxes, and the skill on real LIBERO (LIBERO-goal task 3,
where the opened top drawer would reach over the bowl)."""

from __future__ import annotations

import numpy as np
import pytest

from vlaprobe.configs.env import EnvConfig
from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.experts.clear import Clear, clear_move
from vlaprobe.experts.geometry import CLEAR_GAP

DRAWER = (np.array([-0.08, -0.17, 1.05]), np.array([0.14, 0.03, 1.12]))  # the opened drawer's box
INTO = np.array([0.0, -1.0, 0.0])  # the cabinet lies towards -y


def boxes(*rows: tuple[float, float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(x0, y0, x1, y1) footprints -> (N, 3) lower and upper corners (z 0.9-0.95)."""
    lo = np.array([[r[0], r[1], 0.9] for r in rows])
    hi = np.array([[r[2], r[3], 0.95] for r in rows])
    return lo, hi


def test_an_object_outside_the_drawer_stays() -> None:
    lo, hi = boxes((-0.25, -0.05, -0.15, 0.05))
    assert clear_move(lo, hi, 0, DRAWER, INTO) is None


def test_the_shortest_way_out_that_hits_nothing() -> None:
    bowl = (-0.13, -0.05, -0.03, 0.05)  # 5 cm under the drawer's side
    lo, hi = boxes(bowl)
    move = clear_move(lo, hi, 0, DRAWER, INTO)
    assert move is not None
    assert move[0] == pytest.approx(-(0.05 + CLEAR_GAP)) and move[1] == pytest.approx(0.0)
    # A bottle where that move would put the bowl: the bowl steps aside along y as well.
    lo, hi = boxes(bowl, (-0.22, -0.06, -0.17, -0.01))
    move = clear_move(lo, hi, 0, DRAWER, INTO)
    assert move is not None and move[0] == pytest.approx(-(0.05 + CLEAR_GAP)) and move[1] > 0.0


def test_never_into_the_cabinet() -> None:
    lo, hi = boxes((0.0, -0.1, 0.06, -0.02))  # under the drawer's middle: out along +y (-y is the cabinet)
    move = clear_move(lo, hi, 0, DRAWER, INTO)
    assert move is not None and move[1] > 0.0


@pytest.mark.libero
def test_the_bowl_is_pushed_out_of_the_top_drawers_way() -> None:
    region = "wooden_cabinet_1_top_region"
    with LiberoTaskEnv(3, EnvConfig(suite="libero_goal", render=False)) as env:
        env.reset(0)
        skill = Clear(env, "akita_black_bowl_1", region)
        bowl = env.scene.tabletop.index("akita_black_bowl_1")

        def move() -> np.ndarray | None:
            state = env.world_state()
            return clear_move(
                state.aabb_lo, state.aabb_hi, bowl, skill._drawer.opened_box(), -skill._drawer.out
            )

        assert move() is not None  # init 0: the bowl stands where the drawer opens
        steps = 0
        while steps < 200 and not skill.done:
            env.step(skill.act())
            steps += 1
        assert skill.done, skill.phase
        lo, hi = env.world_state().aabb_lo[bowl], env.world_state().aabb_hi[bowl]
        box_lo, box_hi = skill._drawer.opened_box()
        assert np.any((hi[:2] < box_lo[:2]) | (lo[:2] > box_hi[:2])), (lo, hi)  # clear of the drawer's box
        assert hi[2] - lo[2] < 0.06  # pushed upright, not tipped


@pytest.mark.libero
def test_a_bowl_displaced_clear_of_the_drawer_ends_the_push() -> None:
    """``--perturb``'s displacement lands the bowl away from the drawer while the skill approaches it: the skill
    aims again, finds it clear and retreats (before, it kept pushing towards the spot aimed at first)."""
    with LiberoTaskEnv(3, EnvConfig(suite="libero_goal", render=False)) as env:
        env.reset(0)
        skill = Clear(env, "akita_black_bowl_1", "wooden_cabinet_1_top_region")
        bowl = env.scene.tabletop.index("akita_black_bowl_1")
        assert not skill.done  # init 0: the bowl stands where the drawer opens
        for _ in range(10):
            env.step(skill.act())
        env.place_object("akita_black_bowl_1", (-0.12, 0.2))
        steps = 0
        while steps < 120 and not skill.done:
            assert steps == 0 or skill.phase == "retreat", skill.phase
            env.step(skill.act())
            steps += 1
        assert skill.done
        assert np.linalg.norm(env.world_state().pos[bowl, :2] - [-0.12, 0.2]) < 0.02  # left where it landed
