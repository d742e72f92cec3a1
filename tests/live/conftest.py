"""Probes for the live tests: a small store collected from the fake simulator and model, and probes on it."""

from __future__ import annotations

from pathlib import Path

import pytest
from tests.collection.fakes import make_fake_worker

from vlaprobe.collection.collect import collect
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.train import TrainConfig


@pytest.fixture(scope="session")
def fake_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run folder with ``activations/`` (fake episodes) and ``probes/`` trained on them."""
    root = tmp_path_factory.mktemp("run")
    cfg = CollectConfig(
        out=root / "activations",
        tasks=(0, 1, 2),
        episodes_per_task=4,
        max_tries_per_task=12,
        progress=False,
        env=EnvConfig(max_steps=6, image_size=16),
    )
    collect(cfg, make_fake_worker)
    from vlaprobe.probes.train import train_probes

    train_probes(
        TrainConfig(
            store=cfg.out, out=root / "probes", bootstrap=20, auprc_bootstrap=5, shuffled_control=False
        )
    )
    return root
