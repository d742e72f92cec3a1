"""Adding to a store: every defining setting is compared (and refused in one line naming both values, before any
work, the store untouched), one writer at a time, and a refused run leaves nothing behind."""

from __future__ import annotations

import dataclasses
import re
import signal
from functools import partial
from pathlib import Path
from typing import Any

import pytest
from tests.collection.fakes import (
    GOAL,
    FakeEnv,
    FakePolicy,
    fake_driver,
    fake_scenes,
    fake_tasks,
    make_fake_worker,
    serial_keys,
)
from tests.collection.test_collect import collecting, config, keys

from vlaprobe.collection.collect import collect
from vlaprobe.collection.store import read_meta
from vlaprobe.collection.worker import Worker
from vlaprobe.collection.writer import DEFINING, LAYOUTS_BEFORE, StoreWriter
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.configs.takeover import TakeoverConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols import Labeler

REPO = Path(__file__).resolve().parents[2]


class OtherIdPolicy(FakePolicy):
    def __init__(self, cfg: Any, suite: str = "libero_spatial") -> None:
        super().__init__(cfg, suite)
        self.model_id = "other"


class RevisedPolicy(FakePolicy):
    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "revision": "b"}


class DeeperPolicy(FakePolicy):
    def __init__(self, cfg: Any, suite: str = "libero_spatial") -> None:
        super().__init__(cfg, suite)
        self.num_hidden_states += 1


class WiderPolicy(FakePolicy):
    def __init__(self, cfg: Any, suite: str = "libero_spatial") -> None:
        super().__init__(cfg, suite)
        self.hidden_size += 1


class CupEnv(FakeEnv):
    """The fake scene with one more object: another atom vocabulary."""

    def __init__(self, task: int, cfg: Any) -> None:
        super().__init__(task, cfg)
        self.scene = dataclasses.replace(self.scene, pickupable=(*self.scene.pickupable, "cup"))
        self.labeler = Labeler(self.scene, GOAL)


def cup_scenes(cfg: Any, tasks: Any) -> list[Any]:
    return [CupEnv(t, cfg).scene for t in tasks]


def worker(**parts: Any) -> Any:
    pieces = {
        "make_env": FakeEnv,
        "make_policy": FakePolicy,
        "make_driver": fake_driver,
        "list_tasks": fake_tasks,
        "task_scenes": fake_scenes,
        **parts,
    }
    return partial(Worker, **pieces)


def no_worker(_cfg: CollectConfig) -> None:
    raise AssertionError("the store should be refused before any model is loaded")


def snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    """(size, mtime) of every file under ``folder`` and beside it: what a refused run must not change."""
    files = [p for p in folder.parent.rglob("*") if p.is_file()]
    return {str(p): (p.stat().st_size, p.stat().st_mtime_ns) for p in files}


BASE: dict[str, Any] = {"tasks": (0,), "episodes_per_task": 1}
# setting -> (the store's settings, this run's changes, the message; the worker when the model differs)
CASES: dict[str, tuple[dict[str, Any], dict[str, Any], str, Any]] = {
    "model_id": (
        {},
        {},
        '--model: the model id is "fake" in the store but "other"',
        worker(make_policy=OtherIdPolicy),
    ),
    "model": (
        {},
        {},
        '--model: the model.revision is null in the store but "b"',
        worker(make_policy=RevisedPolicy),
    ),
    "atom_names": ({}, {}, "the atom vocabulary.", worker(make_env=CupEnv, task_scenes=cup_scenes)),
    "num_hidden_states": (
        {},
        {},
        "number of hidden states is 4 in the store but 5",
        worker(make_policy=DeeperPolicy),
    ),
    "hidden_size": (
        {},
        {},
        "--model: the hidden size is 8 in the store but 9",
        worker(make_policy=WiderPolicy),
    ),
    "pooling": (
        {},
        {"policy": PolicyConfig(pooling="mean_text")},
        '--pooling is "last_prompt" in the store but "mean_text"',
        None,
    ),
    "driver": ({}, {"driver": "policy"}, '--driver is "expert" in the store but "policy"', None),
    "dagger_beta": (
        {"driver": "dagger", "dagger_beta": 0.5},
        {"driver": "dagger", "dagger_beta": 0.2},
        "--dagger-beta is 0.5 in the store but 0.2",
        None,
    ),
    "expert_faults": (
        {},  # the fake expert cannot be faulted: the store is written without faults
        {"expert_faults": "release=0.5"},
        '--expert-faults is "" in the store but "release=0.5"',
        None,
    ),
    "suite": ({}, {"env": EnvConfig(suite="libero_object", max_steps=6, image_size=16)}, "--env.suite", None),
    "env": (
        {},
        {"env": EnvConfig(max_steps=7, image_size=16)},
        "--env.max-steps is 6 in the store but 7",
        None,
    ),
    "seed": ({}, {"policy": PolicyConfig(seed=3)}, "--seed is 0 in the store but 3", None),
    "post_success_steps": (
        {},
        {"post_success_steps": 2},
        "--post-success-steps is 10 in the store but 2",
        None,
    ),
    "inits": (
        {},
        {"env": EnvConfig(max_steps=6, image_size=16, inits="sampled")},
        '--inits is "fixed" in the store but "sampled"',
        None,
    ),
    "layouts": ({}, {}, "", None),  # its own test below
    "perturb": (
        {"perturb": "drop=0.2"},
        {"perturb": "knock_off=1"},
        '--perturb is "drop=0.2" in the store but "knock_off=1"',
        None,
    ),
    "first_init": ({}, {"first_init": 2}, "--first-init is 0 in the store but 2", None),
    "keep_failed": ({}, {"keep_failed": True}, "--keep-failed is false in the store but true", None),
    "takeover": (
        {"driver": "policy"},
        {"driver": "policy", "intervention": TakeoverConfig(takeover="alarm")},
        '--takeover and its settings is "" in the store but "alarm until=subgoal steps=150',
        None,
    ),
}


def test_every_defining_setting_has_a_case() -> None:
    assert sorted(CASES) == sorted(s.key for s in DEFINING)


def _refused(cfg: CollectConfig, make_worker: Any, message: str) -> None:
    before = snapshot(cfg.out)
    with pytest.raises(VlaprobeError) as err:
        collect(cfg, make_worker)
    text = str(err.value)
    assert message in text and "in this run" in text and "\n" not in text, text
    assert snapshot(cfg.out) == before


@pytest.mark.parametrize("key", [k for k in CASES if k != "layouts"])
def test_a_resume_with_another_defining_setting_is_refused(tmp_path: Path, key: str) -> None:
    stored, changes, message, other_worker = CASES[key]
    cfg = config(tmp_path / "store", **{**BASE, **stored})
    collect(cfg, make_fake_worker)
    _refused(dataclasses.replace(cfg, **changes), other_worker or no_worker, message)


def test_adding_without_perturbations_or_with_fixed_inits_is_refused(tmp_path: Path) -> None:
    perturbed = config(tmp_path / "perturbed", **BASE, perturb="drop=0.2")
    collect(perturbed, make_fake_worker)
    _refused(
        dataclasses.replace(perturbed, perturb=""), no_worker, '--perturb is "drop=0.2" in the store but ""'
    )
    sampled = config(tmp_path / "sampled", **BASE, env=EnvConfig(max_steps=6, image_size=16, inits="sampled"))
    collect(sampled, make_fake_worker)
    assert read_meta(sampled.out)["inits"] == "sampled"
    _refused(config(sampled.out, **BASE), no_worker, '--inits is "sampled" in the store but "fixed"')


def _forget(store: Path, *keys: str) -> None:
    """Drop metadata keys, as a store written before they were recorded lacks them."""
    with StoreWriter.open(store, read_meta(store)) as writer:
        writer.meta = {k: v for k, v in writer.meta.items() if k not in keys}
        writer.update_meta()
    assert not set(keys) & set(read_meta(store))


def test_a_sampled_store_of_seed_independent_layouts_is_not_resumed(tmp_path: Path) -> None:
    cfg = config(tmp_path / "store", **BASE, env=EnvConfig(max_steps=6, image_size=16, inits="sampled"))
    collect(cfg, make_fake_worker)
    _forget(cfg.out, "layouts")
    _refused(cfg, no_worker, f'--inits: the layouts is "{LAYOUTS_BEFORE}" in the store but')


def test_an_older_store_without_first_init_and_keep_failed_reads_them_from_its_config(tmp_path: Path) -> None:
    cfg = config(tmp_path / "store", **BASE, first_init=2, keep_failed=True)
    collect(cfg, make_fake_worker)
    _forget(cfg.out, "first_init", "keep_failed")
    _refused(dataclasses.replace(cfg, first_init=0), no_worker, "--first-init is 2 in the store but 0")
    _refused(
        dataclasses.replace(cfg, keep_failed=False), no_worker, "--keep-failed is true in the store but false"
    )
    collect(dataclasses.replace(cfg, episodes_per_task=2), make_fake_worker)  # the same settings resume


def test_the_same_settings_resume(tmp_path: Path) -> None:
    cfg = config(tmp_path / "store", **BASE, perturb="drop=0.2", first_init=1, keep_failed=True)
    collect(cfg, make_fake_worker)
    collect(dataclasses.replace(cfg, episodes_per_task=2, tasks=(0, 1)), make_fake_worker)
    assert len(keys(cfg.out)) >= 4


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"first_init": 12}, "--first-init 12 leaves no init state"),
        ({"tasks": (5,)}, "--tasks [5] do not exist"),
    ],
)
def test_a_refused_collection_leaves_nothing_behind(
    tmp_path: Path, changes: dict[str, Any], message: str
) -> None:
    new = tmp_path / "runs" / "new" / "store"
    with pytest.raises(VlaprobeError, match=re.escape(message)):
        collect(config(new, **{**BASE, **changes}), make_fake_worker)
    assert list(tmp_path.iterdir()) == []
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(VlaprobeError, match=re.escape(message)):
        collect(config(empty, **{**BASE, **changes}), make_fake_worker)
    assert list(tmp_path.iterdir()) == [empty] and list(empty.iterdir()) == []


def test_two_collections_into_one_store_then_kill_9_of_the_first(tmp_path: Path) -> None:
    out = tmp_path / "store"
    proc = collecting(out, 1)
    try:
        before = keys(out)
        with pytest.raises(VlaprobeError, match=f"--out {out} is being written by pid {proc.pid} \\(.*-c"):
            collect(config(out, tasks=(0, 1, 2)), no_worker)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        proc.kill()
    assert keys(out)[: len(before)] == before
    collect(config(out, tasks=(0, 1, 2)), make_fake_worker)  # the killed holder's lock is taken over
    assert keys(out) == serial_keys([0, 1, 2], 3, 8, keep_failed=False)
