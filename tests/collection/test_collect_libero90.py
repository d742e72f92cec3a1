"""`vlaprobe collect --suite libero_90` on one task, a few steps of the scripted expert with the tiny model observing
(slow: libero mark): the store is LIBERO-90's, with the task's own vocabulary and goal."""

from __future__ import annotations

from pathlib import Path

import pytest

from vlaprobe.cli import main as cli_main
from vlaprobe.collection.store import ActivationStore
from vlaprobe.envs.bddl_scene import task_scene
from vlaprobe.envs.libero import suite_tasks
from vlaprobe.symbols import HEADS
from vlaprobe.symbols.vocabulary import build_vocabulary

pytestmark = [pytest.mark.libero, pytest.mark.heavy, pytest.mark.timeout(600)]
SUITE, TASK, STEPS = "libero_90", 46, 8  # the alphabet soup into the basket (the body pick), a living room


def test_collect_libero_90_stores_a_few_expert_steps_of_one_task(tmp_path: Path) -> None:
    out = tmp_path / "store"
    argv = [
        "collect", "--suite", SUITE, "--out", str(out), "--tasks", str(TASK), "--episodes-per-task", "1",
        "--max-tries-per-task", "1", "--keep-failed", "--env.max-steps", str(STEPS), "--workers", "1",
        "--model", "tiny", "--device", "cpu", "--env.image-size", "64", "--no-progress",
    ]  # fmt: skip
    assert cli_main(argv) == 0
    store = ActivationStore.open(out)
    assert store.suite == SUITE
    vocab = build_vocabulary(task_scene(SUITE, TASK))
    assert store.atom_names == {h: list(vocab.atoms(h)) for h in HEADS}
    (info,) = store.episodes()
    assert (info.task, info.init, info.success) == (TASK, 0, False)  # 8 steps: the soup is not in yet
    attrs = store.episode(info.key).attributes
    assert attrs.instruction == dict(suite_tasks(SUITE))[TASK] and attrs.scene == task_scene(SUITE, TASK)
    rows = store.episode(info.key).records()
    assert sum(1 for _ in rows) == STEPS
