"""`vlaprobe cognition` on a real LIBERO-goal store: an episode with no pick-and-place goal is followed through its
task's own goal conjunction (TurnOn), read from the BDDL in the stored scene (slow: libero mark). Random probes:
the truth side is what is checked. And over every task of every suite, which goals no atom follows."""

from __future__ import annotations

from pathlib import Path

import pytest
from tests.live.fakes import random_probes

from vlaprobe.cognition.monitor import monitor
from vlaprobe.cognition.plan import stored_task_goal, task_goal, unreadable
from vlaprobe.collection.collect import collect
from vlaprobe.collection.store import ActivationStore
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.configs.env import SUITES, EnvConfig
from vlaprobe.configs.monitor import MonitorConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.envs.bddl_scene import task_goal as bddl_goal
from vlaprobe.envs.bddl_scene import task_scene
from vlaprobe.envs.libero import suite_tasks
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols.vocabulary import build_vocabulary

pytestmark = [pytest.mark.libero, pytest.mark.timeout(900), pytest.mark.heavy]
SUITE, TASK = "libero_goal", 7  # turn on the stove


def test_monitor_follows_a_libero_goal_episode_to_its_goal(tmp_path: Path) -> None:
    cfg = CollectConfig(
        out=tmp_path / "store", tasks=(TASK,), episodes_per_task=1, progress=False,
        policy=PolicyConfig(model="tiny", device="cpu"), env=EnvConfig(suite=SUITE, image_size=64),
    )  # fmt: skip
    assert collect(cfg).published
    store = ActivationStore.open(cfg.out)
    (info,) = store.episodes()
    attrs = store.episode(info.key).attributes
    assert info.success and attrs.goal is None  # no pick-and-place goal recorded: the BDDL's is used
    goal = stored_task_goal(store.suite, info.task, attrs, "the episode")
    assert str(goal) == "TurnOn(flat_stove_1)"
    atoms = {h: list(store.atom_names[h]) for h in ("object", "action")}
    probes = random_probes(tmp_path / "probes", store.model_id, store.num_hidden_states, store.hidden_size, atoms,
                           suite=SUITE)  # fmt: skip
    result = monitor(MonitorConfig(store=cfg.out, probes=probes, out=tmp_path / "m", all_episodes=True))
    (figures,) = result.per_episode
    assert figures.goal_step_truth is not None and figures.goal_step_truth <= figures.steps
    attrs.scene = None
    with pytest.raises(VlaprobeError, match="records neither a goal nor a scene"):
        stored_task_goal(store.suite, info.task, attrs, "the episode")


def test_the_goals_no_atom_follows_are_those_onto_a_table_region() -> None:
    """Over every task of every suite (`vlaprobe run` takes them all), the cognition follows every goal but those
    ``On`` a placement region of a table: the episodes `vlaprobe cognition` leaves out, named."""
    unfollowable = {}
    for suite in SUITES:
        for task, _ in suite_tasks(suite):
            scene = task_scene(suite, task)
            vocab = build_vocabulary(scene)
            problem = unreadable(
                task_goal(bddl_goal(suite, task), scene), vocab.object_atoms + vocab.action_atoms
            )
            if problem is not None:
                unfollowable[suite, task] = problem
    libero_90 = {34, 37, 69, 70, 76, 84, 85}  # in front of a mug, beside a plate or a caddy
    assert set(unfollowable) == {("libero_goal", 5), ("libero_10", 6)} | {("libero_90", t) for t in libero_90}
    assert "main_table_stove_front_region" in unfollowable["libero_goal", 5]
    assert "living_room_table_plate_right_region" in unfollowable["libero_10", 6]
    assert all("placement region of the table" in p for p in unfollowable.values())
