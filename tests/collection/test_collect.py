"""`collect` end to end with fake simulator/model/expert: contents, resume after kill -9, workers, Ray, info."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from tests.collection.fakes import (
    GOAL,
    HIDDEN,
    LAYERS,
    SCENE,
    make_fake_worker,
    serial_keys,
    succeeds,
    success_step,
)

from vlaprobe.collection.collect import collect
from vlaprobe.collection.episode import stored_scene, world_states
from vlaprobe.collection.info import info
from vlaprobe.collection.store import ActivationStore
from vlaprobe.configs import config_to_dict
from vlaprobe.configs.collect import CollectConfig, InfoConfig
from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols import Labeler

REPO = Path(__file__).resolve().parents[2]


def config(out: Path, **changes) -> CollectConfig:
    base = dict(
        out=out,
        tasks=(0, 2),
        episodes_per_task=3,
        max_tries_per_task=8,
        progress=False,
        env=EnvConfig(max_steps=6, image_size=16),
    )
    return CollectConfig(**{**base, **changes})


def keys(path: Path) -> list[str]:
    return [e.key for e in ActivationStore.open(path).episodes()]


def test_collect_records_consistent_steps(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = config(tmp_path / "store")
    result = collect(cfg, make_fake_worker)
    assert keys(cfg.out) == serial_keys([0, 2], 3, 8, keep_failed=False) == result.published
    assert result.kept == {0: (3, 3), 2: (3, 4)} and result.exhausted == []
    # task 0's simulator was built to describe the suite; task 2's once, for its first episode
    assert result.simulators_built == 1 and result.build_seconds > 0

    store = ActivationStore.open(cfg.out)
    assert (
        store.num_hidden_states == LAYERS and store.hidden_size == HIDDEN and store.pooling == "last_prompt"
    )
    labeler = Labeler(SCENE, GOAL)
    assert store.atom_names == {
        "object": list(labeler.vocabulary.object_atoms),
        "action": list(labeler.vocabulary.action_atoms),
    }
    for info_, ep in store.iter_episodes():
        assert (
            info_.success
            and info_.driver == "expert"
            and ep["hidden"].shape == (LAYERS, info_.length, HIDDEN)
        )
        np.testing.assert_array_equal(ep["step"], np.arange(info_.length))
        assert ep["image"].shape == (info_.length, 16, 16, 3) and ep["image"].dtype == np.uint8
        assert ep["action"].shape == ep["predicted_action"].shape == (info_.length, 7)
        # The expert acted, the model only watched.
        assert not np.allclose(ep["action"], ep["predicted_action"])
        # The labels of each row are the detectors applied to that row's stored world state.
        scene, goal = stored_scene(ep.attrs)
        relabel = Labeler(scene, goal)
        bits = [relabel(s) for s in world_states(ep)]
        np.testing.assert_array_equal(ep["object_atoms"], np.stack([b[0] for b in bits]))
        np.testing.assert_array_equal(ep["action_atoms"], np.stack([b[1] for b in bits]))
        assert ep.attrs["instruction"] == f"put the bowl on the plate ({info_.task})"
    assert [e.key for e in store.failures()] == ["t02_i01_a00"]

    meta = store.meta
    assert meta["driver"] == "expert" and meta["model_id"] == "fake" and "device" not in meta["model"]
    assert meta["config"] == json.loads(json.dumps(config_to_dict(cfg)))
    assert set(meta["versions"]) >= {"vlaprobe", "torch", "numpy", "zarr", "mujoco", "robosuite", "libero"}
    assert meta["runs"][0]["episodes_added"] == 6 and meta["runs"][0]["device"] == "cpu"
    out = capsys.readouterr().out
    assert "task 2: 3/3 successful episodes, 4 tried" in out and "1 simulator(s) built" in out

    # A rerun has nothing left to do.
    again = collect(cfg, make_fake_worker)
    assert (
        again.published == []
        and again.episodes_run == 0
        and len(ActivationStore.open(cfg.out).meta["runs"]) == 2
    )


def test_keep_failed_budget_and_action_tokens(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = config(
        tmp_path / "store",
        tasks=(1,),
        episodes_per_task=20,
        keep_failed=True,
        policy=PolicyConfig(pooling="action_tokens"),
    )
    result = collect(cfg, make_fake_worker)
    expected = serial_keys([1], 20, 8, keep_failed=True)
    assert keys(cfg.out) == expected and len(expected) == 8
    assert result.exhausted == [1] and "try budget (8 init states) exhausted" in capsys.readouterr().out
    store = ActivationStore.open(cfg.out)
    assert [e.success for e in store.episodes()] == [succeeds(1, i) for i in range(8)]
    failed = next(e for e in store.episodes() if not e.success)
    assert failed.length == 6  # ran to max_steps
    assert store.layer(2, [failed.key]).shape == (6, 7, HIDDEN)


def test_incompatible_settings_are_refused_before_work(tmp_path: Path) -> None:
    cfg = config(tmp_path / "store", tasks=(0,), episodes_per_task=1)
    collect(cfg, make_fake_worker)

    def no_worker(_cfg: CollectConfig) -> None:
        raise AssertionError("the store should be refused before any worker is built")

    with pytest.raises(VlaprobeError, match='driver is "expert" in the store but "policy"'):
        collect(dataclasses.replace(cfg, driver="policy"), no_worker)
    with pytest.raises(VlaprobeError, match=r"--env\.max-steps is 6 in the store but 7 in this run"):
        collect(dataclasses.replace(cfg, env=EnvConfig(max_steps=7, image_size=16)), no_worker)
    with pytest.raises(VlaprobeError, match=r"--tasks \[5\] do not exist"):
        collect(dataclasses.replace(cfg, tasks=(5,)), make_fake_worker)
    with pytest.raises(VlaprobeError, match="at least 1"):
        collect(dataclasses.replace(cfg, episodes_per_task=0), make_fake_worker)


def test_two_workers_give_the_same_episodes_as_one(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.syspath_prepend(str(REPO))  # spawned workers import the fakes by name
    cfg = config(tmp_path / "store", tasks=(0, 1, 2), workers=2, keep_failed=True)
    result = collect(cfg, make_fake_worker)
    assert keys(cfg.out) == serial_keys([0, 1, 2], 3, 8, keep_failed=True)
    assert not (cfg.out / ".staging").exists()
    assert result.episodes_run >= len(keys(cfg.out))
    assert 2 <= result.simulators_built <= 2 * 3  # at most every task on both workers


RUNNER = """
import sys
from pathlib import Path
from tests.collection.fakes import make_fake_worker
from tests.collection.test_collect import config
from vlaprobe.collection.collect import collect
collect(config(Path(sys.argv[1]), tasks=(0, 1, 2)), make_fake_worker)
"""


def collecting(out: Path, episodes: int) -> subprocess.Popen[bytes]:
    """A slowed-down collection of tasks 0-2 into ``out`` in another process, once it has published ``episodes``."""
    env = {**os.environ, "FAKE_STEP_SECONDS": "0.05", "PYTHONPATH": f"{REPO}{os.pathsep}{REPO / 'src'}"}
    proc = subprocess.Popen([sys.executable, "-c", RUNNER, str(out)], cwd=REPO, env=env)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and len(list((out / "episodes").glob("t*"))) < episodes:
        time.sleep(0.02)
    return proc


def test_kill_9_then_rerun_equals_uninterrupted(tmp_path: Path) -> None:
    out = tmp_path / "store"
    proc = collecting(out, 2)
    try:
        time.sleep(0.12)  # into the next episode
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        proc.kill()
    partial = keys(out)
    full = serial_keys([0, 1, 2], 3, 8, keep_failed=False)
    assert 2 <= len(partial) < len(full) and partial == full[: len(partial)]
    collect(config(out, tasks=(0, 1, 2)), make_fake_worker)
    assert keys(out) == full
    assert not (out / ".staging").exists()


def test_ray_workers_give_the_same_episodes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("ray")
    # Ray's worker processes import the fakes by name.
    monkeypatch.setenv("PYTHONPATH", f"{REPO}{os.pathsep}{REPO / 'src'}")
    cfg = config(tmp_path / "store", workers=2, ray="local")
    collect(cfg, make_fake_worker)
    assert keys(cfg.out) == serial_keys([0, 2], 3, 8, keep_failed=False)


def test_info_json_and_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = config(tmp_path / "store", tasks=(2,), episodes_per_task=2)
    collect(cfg, make_fake_worker)
    capsys.readouterr()
    assert info(InfoConfig(path=cfg.out, json=True)) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["layers"] == LAYERS and doc["hidden_size"] == HIDDEN and doc["pooling"] == "last_prompt"
    assert [(e["task"], e["init"], e["attempt"], e["success"]) for e in doc["episodes"]] == [
        (2, 0, 0, True),
        (2, 2, 0, True),
    ]
    assert all(isinstance(e["length"], int) and e["length"] > 0 for e in doc["episodes"])
    info(InfoConfig(path=cfg.out))
    table = capsys.readouterr().out
    assert "2 (2 successful)" in table and "put the bowl on the plate (2)" in table
    with pytest.raises(VlaprobeError, match="not an activation store"):
        info(InfoConfig(path=tmp_path))


def test_post_success_steps_record_rows_after_success_and_the_success_step(tmp_path: Path) -> None:
    cfg = config(
        tmp_path / "store", tasks=(0,), post_success_steps=2, env=EnvConfig(max_steps=10, image_size=16)
    )
    collect(cfg, make_fake_worker)
    store = ActivationStore.open(cfg.out)
    for info_, ep in store.iter_episodes():
        s = success_step(info_.task, info_.init)
        assert info_.success_step == s and info_.length == s + 3
        assert np.isnan(ep["action"][-1]).all() and not np.isnan(ep["action"][:-1]).any()
    assert {"success_step"} <= set(store.summary()["episodes"][0])
    # Another post-success budget is another dataset: refused before any work.
    with pytest.raises(VlaprobeError, match="post_success_steps"):
        collect(dataclasses.replace(cfg, post_success_steps=0), make_fake_worker)
    with pytest.raises(VlaprobeError, match="post-success-steps"):
        collect(dataclasses.replace(cfg, out=tmp_path / "other", post_success_steps=-1), make_fake_worker)


def test_dagger_store_keeps_the_experts_labels_and_its_beta(tmp_path: Path) -> None:
    cfg = config(tmp_path / "store", tasks=(1,), episodes_per_task=3, keep_failed=True, driver="dagger")
    collect(dataclasses.replace(cfg, dagger_beta=0.5), make_fake_worker)
    store = ActivationStore.open(cfg.out)
    assert store.meta["driver"] == "dagger" and store.meta["dagger_beta"] == 0.5
    by_model = by_expert = 0
    for e in store.episodes():
        arrays = store.episode(e.key)
        expert, action = np.asarray(arrays["expert_action"]), np.asarray(arrays["action"])
        predicted = np.asarray(arrays["predicted_action"])
        assert expert.shape == (e.length, 7) and expert.dtype == np.float32
        acted = np.isfinite(action).all(axis=1)
        assert (np.isfinite(expert).all(axis=1) == acted).all()  # NaN only on the terminal row
        by_expert += int(np.all(action[acted] == expert[acted], axis=1).sum())
        by_model += int(np.all(action[acted] == predicted[acted], axis=1).sum())
    assert by_expert > 0 and by_model > 0  # beta 0.5: both acted
    with pytest.raises(VlaprobeError, match=r"--dagger-beta is 0\.5 in the store but 0\.2"):
        collect(dataclasses.replace(cfg, dagger_beta=0.2), make_fake_worker)
    with pytest.raises(VlaprobeError, match="--dagger-beta applies to --driver dagger only"):
        collect(config(tmp_path / "other", dagger_beta=0.5), make_fake_worker)
    with pytest.raises(VlaprobeError, match=r"--dagger-beta must be a number in \[0, 1\]"):
        collect(dataclasses.replace(cfg, dagger_beta=2.0), make_fake_worker)
    expert_store = config(tmp_path / "expert", tasks=(1,), episodes_per_task=1)
    collect(expert_store, make_fake_worker)
    plain = ActivationStore.open(expert_store.out)
    assert "expert_action" not in plain.episode(plain.episodes()[0].key)
