"""The scripted expert on real LIBERO: it solves an ordinary task and the top-drawer task, and the ground-truth
``grasped`` detector holds steadily while the expert carries the bowl by its rim."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from vlaprobe.configs.env import EnvConfig
from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.experts import ScriptedExpert
from vlaprobe.experts.geometry import _box_distance, _clip_below, _down_rotation
from vlaprobe.symbols import atom

BOWL = "akita_black_bowl_1"
PLATE = "plate_1"
ORDINARY_TASK = 0  # "... between the plate and the ramekin ...": the bowl stands on the table
DRAWER_TASK = 4  # "... in the top drawer of the wooden cabinet ...": the case a naive grasp fails
HELD_LIFT = 0.03  # "held": the bowl is this far above where it started and not on the plate


@dataclass
class Episode:
    success: bool
    steps: int
    start_atoms: set[str] = field(default_factory=set)
    phases: list[str] = field(default_factory=list)
    held: list[bool] = field(default_factory=list)
    grasped: list[bool] = field(default_factory=list)
    actions: list[np.ndarray] = field(default_factory=list)


def run_episode(task: int, init: int = 0, max_steps: int = 300) -> Episode:
    with LiberoTaskEnv(task, EnvConfig(render=False)) as env:
        np.random.seed(task)  # LIBERO's soft reset draws from numpy's global generator
        obs = env.reset(init)
        expert = ScriptedExpert(env)
        vocab = env.labeler.vocabulary
        grasped_index = vocab.action_atoms.index(atom("grasped", BOWL))
        on_plate_index = vocab.object_atoms.index(atom("on", BOWL, PLATE))
        bowl = env.scene.tabletop.index(BOWL)
        start_z = float(env.world_state().pos[bowl, 2])
        obj_bits, _ = env.labels()
        episode = Episode(success=False, steps=0)
        episode.start_atoms = {a for a, bit in zip(vocab.object_atoms, obj_bits, strict=True) if bit}
        while episode.steps < max_steps and not obs.success:
            action = expert.act()
            episode.actions.append(action)
            episode.phases.append(expert.phase)
            obs = env.step(action)
            episode.steps += 1
            obj_bits, act_bits = env.labels()
            lifted = env.world_state().pos[bowl, 2] > start_z + HELD_LIFT
            episode.held.append(bool(lifted and not obj_bits[on_plate_index]))
            episode.grasped.append(bool(act_bits[grasped_index]))
        episode.success = obs.success
        return episode


@pytest.fixture(scope="module")
def episodes() -> dict[int, Episode]:
    return {task: run_episode(task) for task in (ORDINARY_TASK, DRAWER_TASK)}


@pytest.mark.libero
@pytest.mark.parametrize("task", [ORDINARY_TASK, DRAWER_TASK])
def test_expert_solves_the_task(episodes: dict[int, Episode], task: int) -> None:
    episode = episodes[task]
    in_drawer = atom("inside", BOWL, "wooden_cabinet_1_top_region") in episode.start_atoms
    assert in_drawer == (task == DRAWER_TASK)
    assert episode.success, f"task {task} failed after {episode.steps} steps in phase {episode.phases[-1]}"
    # It got there by picking and placing, through the phases in order.
    seen = list(dict.fromkeys(episode.phases))
    for before, after in [
        ("approach", "descend"),
        ("descend", "close"),
        ("close", "lift"),
        ("lift", "carry"),
    ]:
        assert seen.index(before) < seen.index(after)
    actions = np.array(episode.actions)
    assert actions.shape == (episode.steps, 7) and actions.dtype == np.float64
    assert np.all(np.abs(actions) <= 1.0)
    assert set(np.unique(actions[:, 6])) <= {-1.0, 1.0}


@pytest.mark.libero
def test_grasped_detector_holds_while_the_bowl_is_carried(episodes: dict[int, Episode]) -> None:
    held = np.concatenate([e.held for e in episodes.values()])
    grasped = np.concatenate([e.grasped for e in episodes.values()])
    closed = np.concatenate([np.array(e.actions)[:, 6] > 0 for e in episodes.values()])
    assert held.sum() >= 40, "the bowl was hardly ever carried"
    # While the fingers are commanded shut on the rim, grasped(bowl) must not flicker (robosuite's two-pad contact
    # check is true on only ~80% of these steps). Measured: 100%.
    assert grasped[held & closed].mean() >= 0.98
    # Over all held steps, the only misses are the step or two after the release while the bowl drops onto the
    # plate (the gripper is commanded open: nothing is grasped any more). Measured: 98%.
    assert grasped[held].mean() >= 0.9
    # And it is not simply always true: before the first close it is false.
    for episode in episodes.values():
        first_close = episode.phases.index("close")
        assert not any(episode.grasped[:first_close])


def test_box_distance_and_grip_frame() -> None:
    box = (np.zeros((1, 3)), np.eye(3)[None], np.array([[0.1, 0.2, 0.3]]))
    points = np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.4, 0.6, 0.0]])
    np.testing.assert_allclose(_box_distance(points, *box)[:, 0], [0.0, 0.3, np.hypot(0.3, 0.4)])
    # A box turned 90 degrees about z swaps its x and y extents.
    turned = (np.zeros((1, 3)), np.array([[[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]]), box[2])
    np.testing.assert_allclose(_box_distance(np.array([[0.3, 0.0, 0.0]]), *turned), [[0.1]])
    axis = np.array([np.cos(0.7), np.sin(0.7), 0.0])
    rot = _down_rotation(axis)
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(rot), 1.0)
    np.testing.assert_allclose(rot[:, 0], axis)
    np.testing.assert_allclose(rot[:, 2], [0.0, 0.0, -1.0])


def test_clip_below_keeps_what_stands_above() -> None:
    yaw = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # upright, turned about z
    tilted = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(0.5), -np.sin(0.5)], [0.0, np.sin(0.5), np.cos(0.5)]])
    centre = np.array([[0.0, 0.0, 0.5], [1.0, 0.0, 0.05], [2.0, 0.0, 0.5], [3.0, 0.0, 0.5]])
    rot = np.stack([np.eye(3), yaw, yaw, tilted])
    half = np.array([[0.1, 0.1, 1.0], [0.1, 0.2, 0.04], [0.1, 0.2, 0.3], [0.1, 0.1, 1.0]])
    c, r, h = _clip_below(centre, rot, half, 0.3)
    np.testing.assert_allclose(r, rot[[0, 2, 3]])
    # The box under the cut goes; the tall ones keep only their part above z = 0.3; a tilted one is left whole.
    np.testing.assert_allclose(c[:, 0], [0.0, 2.0, 3.0])
    np.testing.assert_allclose(c[:2, 2] - h[:2, 2], [0.3, 0.3])
    np.testing.assert_allclose(c[:2, 2] + h[:2, 2], [1.5, 0.8])
    np.testing.assert_allclose(h[:2, :2], half[[0, 2], :2])
    np.testing.assert_allclose(c[2], centre[3])
    np.testing.assert_allclose(h[2], half[3])
