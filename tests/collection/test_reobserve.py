"""Re-observing a store with another model: same episodes and labels, that model's batched hidden states."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vlaprobe.collection.reobserve import reobserve
from vlaprobe.collection.store import ActivationStore, EpisodeInfo, episode_key
from vlaprobe.collection.writer import StoreWriter
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.policies import make_policy

ATOMS = {"object": ["on(a,b)", "on(b,a)"], "action": ["grasped(a)"]}


def _source(path: Path) -> None:
    meta = {
        "atom_names": ATOMS,
        "model_id": "first",
        "model": {"name": "first"},
        "num_hidden_states": 3,
        "hidden_size": 4,
        "pooling": "last_prompt",
        "driver": "expert",
        "suite": "libero_spatial",
        "env": {"image_size": 256},
        "seed": 0,
    }
    with StoreWriter.open(path, meta) as w:
        for task, length in ((0, 3), (1, 2)):
            rng = np.random.default_rng(task)
            info = EpisodeInfo(episode_key(task, 0), task, 0, 0, True, length, seed=1, driver="expert")
            arrays = {
                "hidden": np.zeros((3, length, 4), np.float16),
                "object_atoms": rng.random((length, 2)) < 0.5,
                "action_atoms": rng.random((length, 1)) < 0.5,
                "image": rng.integers(0, 255, (length, 224, 224, 3), dtype=np.uint8),
                "action": rng.standard_normal((length, 7)).astype(np.float32),
                "predicted_action": np.zeros((length, 7), np.float32),
                "world/pos": rng.standard_normal((length, 7, 3)),
            }
            w.write_episode(info, arrays, {"instruction": f"put the bowl on plate {task}"})
        w.mark_failed(EpisodeInfo(episode_key(2, 0), 2, 0, 0, False, 0, seed=1, driver="expert"))


def test_copy_has_the_new_observers_states_and_the_same_episodes(tmp_path: Path) -> None:
    _source(tmp_path / "a")
    cfg = PolicyConfig(model="tiny", device="cpu")
    assert reobserve(tmp_path / "a", tmp_path / "b", cfg, batch=2) == ["t00_i00_a00", "t01_i00_a00"]
    a, b = ActivationStore.open(tmp_path / "a"), ActivationStore.open(tmp_path / "b")
    policy = make_policy(cfg)
    assert (b.model_id, b.num_hidden_states, b.hidden_size) == (policy.model_id, 33, 64)
    assert [e.key for e in b.failures()] == ["t02_i00_a00"]
    for (info, ea), (info_b, eb) in zip(a.iter_episodes(), b.iter_episodes(), strict=True):
        assert info == info_b and ea.attrs["instruction"] == eb.attrs["instruction"]
        for name in ("image", "object_atoms", "action_atoms", "action", "world/pos"):
            np.testing.assert_array_equal(ea[name], eb[name])
        assert "predicted_action" not in eb
        ids = policy.prompt_ids(ea.attrs["instruction"])
        for t, image in enumerate(ea["image"]):  # the unbatched prompt pass of a live step
            single = policy.predict(image, ids, "last_prompt").hidden.numpy()
            np.testing.assert_allclose(eb["hidden"][:, t].astype(np.float32), single, rtol=2e-3, atol=2e-3)
    assert reobserve(tmp_path / "a", tmp_path / "b", cfg) == []  # resumed: nothing left to add


def test_refusals(tmp_path: Path) -> None:
    _source(tmp_path / "a")
    with pytest.raises(VlaprobeError, match="other than the source"):
        reobserve(tmp_path / "a", tmp_path / "a", PolicyConfig(device="cpu"))
    with pytest.raises(VlaprobeError, match="action_tokens"):
        reobserve(tmp_path / "a", tmp_path / "c", PolicyConfig(device="cpu", pooling="action_tokens"))


def test_command_copies_and_refuses_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from vlaprobe.cli import main

    _source(tmp_path / "a")
    assert (
        main(
            [
                "reobserve",
                str(tmp_path / "a"),
                "--out",
                str(tmp_path / "b"),
                "--model",
                "tiny",
                "--device",
                "cpu",
            ]
        )
        == 0
    )
    assert "2 episodes observed by tiny (2 in the store)" in capsys.readouterr().out
    assert ActivationStore.open(tmp_path / "b").model_id == make_policy(PolicyConfig(model="tiny")).model_id
    for argv in (
        ["reobserve", str(tmp_path / "nowhere"), "--out", str(tmp_path / "c")],
        ["reobserve", str(tmp_path / "a"), "--out", str(tmp_path / "c"), "--batch", "0"],
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "c").exists()
