"""Demonstration rows: a DAgger store trains on the expert's labels, failed episodes included."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from tests.finetune.helpers import demo_episode, write_dagger_store

from vlaprobe.errors import VlaprobeError
from vlaprobe.finetune.command import finetune
from vlaprobe.finetune.data import load_demonstrations
from vlaprobe.policies.openvla.actions import training_gripper

DEMO_EPISODES = [(task, init, 24) for task in range(3) for init in range(4)]
"""The episodes of the ``demo_store`` fixture (tests/finetune/conftest.py)."""
EPISODES = [(0, 0, 10, False), (0, 1, 12, True), (1, 0, 9, False), (1, 1, 11, False)]


def test_dagger_store_targets_are_the_experts_labels_failed_episodes_too(tmp_path: Path) -> None:
    store = write_dagger_store(tmp_path / "dagger", EPISODES)
    demos = load_demonstrations((store,), 28, success_only=True, drop_noops=False)
    assert [(r.task, r.key) for r in demos.episodes] == [
        (0, "t00_i00_a00"),
        (0, "t00_i01_a00"),
        (1, "t01_i00_a00"),
        (1, "t01_i01_a00"),
    ]
    expected = [
        training_gripper(demo_episode(t, i, n, 28)[1]["action"].astype(np.float64)) for t, i, n, _ in EPISODES
    ]
    np.testing.assert_allclose(demos.actions, np.concatenate(expected), rtol=1e-6)


def test_finetune_learns_from_expert_and_dagger_stores_together(
    fast_cfg, demo_store: Path, tmp_path: Path
) -> None:
    store = write_dagger_store(tmp_path / "dagger", EPISODES)
    cfg = fast_cfg(stores=(demo_store, store), max_steps=4, eval_every=4)
    finetune(cfg)
    summary = json.loads((cfg.out / "summary.json").read_text())
    rows = sum(n for _, _, n in DEMO_EPISODES) + sum(n for _, _, n, _ in EPISODES)
    assert summary["train_episodes"] + summary["val_episodes"] == 12 + len(EPISODES)
    assert summary["train_rows"] + summary["val_rows"] == rows and summary["finished"]


def test_tasks_keep_only_those_tasks_episodes(demo_store: Path, tmp_path: Path) -> None:
    demos = load_demonstrations((demo_store,), 28, drop_noops=False, tasks=(0, 2))
    assert sorted({r.task for r in demos.episodes}) == [0, 2]
    assert len(demos.episodes) == 8 and len(demos.episode) == 8 * 24
    store = write_dagger_store(tmp_path / "dagger", EPISODES)  # tasks 0 and 1 only
    both = load_demonstrations((demo_store, store), 28, drop_noops=False, tasks=(2,))
    assert {r.store for r in both.episodes} == {0} and len(both.episodes) == 4
    with pytest.raises(VlaprobeError, match=r"no demonstration of tasks \[5\] in .*pick --tasks"):
        load_demonstrations((demo_store, store), 28, success_only=False, tasks=(5,))
