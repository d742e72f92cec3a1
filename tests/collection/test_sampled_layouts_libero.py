"""``--inits sampled``: a layout is a function of (suite, task, seed, sample index), and `vlaprobe collect` with the
seed a store records reproduces its layouts bit for bit (on LIBERO, one 1-step episode per store)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tyro

from vlaprobe.collection.collect import collect
from vlaprobe.collection.store import ActivationStore
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.envs.placements import placement_seed

pytestmark = pytest.mark.libero


def _layout(out: Path, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Collect sample 0 of task 0 with ``seed``; its step-0 object positions and image."""
    args = ["--out", str(out), "--seed", str(seed), "--inits", "sampled", "--tasks", "0", "--episodes-per-task",
            "1", "--max-tries-per-task", "1", "--keep-failed", "--model", "tiny", "--device", "cpu",
            "--no-progress", "--env.max-steps", "1", "--env.image-size", "64"]  # fmt: skip
    collect(tyro.cli(CollectConfig, args=args))
    store = ActivationStore.open(out)
    assert store.meta["seed"] == seed and store.meta["inits"] == "sampled"
    info, ep = next(store.iter_episodes())
    draws = ep.attrs["placement_draws"]
    assert ep.attrs["placement_seed"] == placement_seed("libero_spatial", 0, seed, info.init, draws - 1)
    return np.asarray(ep["world/pos"][0]), np.asarray(ep["image"][0])


def test_two_seeds_give_two_layouts_and_the_recorded_seed_reproduces_one(tmp_path: Path) -> None:
    pos11, image11 = _layout(tmp_path / "s11", 11)
    pos12, _ = _layout(tmp_path / "s12", 12)
    again, image_again = _layout(tmp_path / "again", ActivationStore.open(tmp_path / "s11").meta["seed"])
    assert np.abs(pos11 - pos12).max() > 1e-3  # another seed: another layout
    np.testing.assert_array_equal(again, pos11)  # the same seed: the same layout, bit for bit
    np.testing.assert_array_equal(image_again, image11)
