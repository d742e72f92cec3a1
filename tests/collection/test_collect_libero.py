"""Collection with the real pieces: LIBERO, the embedded tiny OpenVLA observing, the scripted expert acting.

Kept short (~3 min on 2 cores): one full successful episode, then 6-step episodes (which all fail, and are
kept with --keep-failed) for the kill -9 / resume and two-worker checks.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from vlaprobe.collection.collect import collect
from vlaprobe.collection.episode import stored_scene, world_states
from vlaprobe.collection.store import ActivationStore
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.symbols import Labeler

pytestmark = pytest.mark.libero

RUNNER = """
import sys, tyro
from vlaprobe.collection.collect import collect
from vlaprobe.configs.collect import CollectConfig
collect(tyro.cli(CollectConfig, args=sys.argv[1:]))
"""


def test_expert_episode_labels_match_detectors_on_stored_states(tmp_path: Path) -> None:
    cfg = CollectConfig(
        out=tmp_path / "store", tasks=(0,), episodes_per_task=1, policy=PolicyConfig(model="tiny", device="cpu"), progress=False,
        env=EnvConfig(image_size=128),
    )  # fmt: skip
    result = collect(cfg)
    assert result.published == ["t00_i00_a00"]
    store = ActivationStore.open(cfg.out)
    assert store.model_id == "tiny-openvla-seed0" and store.num_hidden_states == 33
    assert len(store.atom_names["object"]) == 224 and len(store.atom_names["action"]) == 12
    assert store.meta["versions"]["mujoco"] and store.meta["instructions"]["0"].startswith(
        "pick up the black bowl"
    )
    info, ep = next(store.iter_episodes())
    assert info.success and info.driver == "expert" and 20 < info.length < cfg.env.max_steps
    t = info.length
    assert ep["image"].shape == (t, 224, 224, 3) and ep["hidden"].shape == (33, t, store.hidden_size)
    assert ep["proprio"].shape == (t, 9) and ep["action_tokens"].shape == (t, 7)
    # The expert acted; the model's own prediction is kept beside it.
    assert not np.allclose(ep["action"], ep["predicted_action"])
    np.testing.assert_array_equal(ep["step"], np.arange(t))

    scene, goal = stored_scene(ep.attrs)
    labeler = Labeler(scene, goal)
    assert list(labeler.vocabulary.object_atoms) == store.atom_names["object"]
    bits = [labeler(state) for state in world_states(ep)]
    np.testing.assert_array_equal(ep["object_atoms"], np.stack([b[0] for b in bits]))
    np.testing.assert_array_equal(ep["action_atoms"], np.stack([b[1] for b in bits]))
    grasped = ep["action_atoms"][:, store.atom_names["action"].index("grasped(akita_black_bowl_1)")]
    assert grasped.any() and not grasped[0]  # the bowl gets picked up during the episode


@pytest.mark.serial  # its 10 s waits for a killed collection: timed, so not beside another worker
def test_kill_9_and_resume_and_two_workers_give_the_same_episodes(tmp_path: Path) -> None:
    args = ["--tasks", "0", "--episodes-per-task", "1", "--max-tries-per-task", "3", "--keep-failed",
            "--device", "cpu", "--no-progress", "--env.max-steps", "6", "--env.image-size", "64"]  # fmt: skip
    expected = ["t00_i00_a00", "t00_i01_a00", "t00_i02_a00"]  # 6 steps never succeed: every try is kept

    out = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-c", RUNNER, "--out", str(out), *args], env=dict(os.environ))
    try:
        deadline = time.monotonic() + 150
        while time.monotonic() < deadline and proc.poll() is None and not list(out.glob("episodes/t*")):
            time.sleep(0.05)
        assert proc.poll() is None, "the run ended before it could be killed"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        proc.kill()
    before = [e.key for e in ActivationStore.open(out).episodes()]
    assert before and before == expected[: len(before)] and len(before) < 3
    import tyro

    collect(tyro.cli(CollectConfig, args=["--out", str(out), *args]))
    assert [e.key for e in ActivationStore.open(out).episodes()] == expected
    assert not (out / ".staging").exists()

    two = tmp_path / "two_workers"
    collect(tyro.cli(CollectConfig, args=["--out", str(two), "--workers", "2", *args]))
    assert [e.key for e in ActivationStore.open(two).episodes()] == expected
