"""A small model and a small demonstration store, shared by the fine-tuning tests (written once per session)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from tests.finetune.helpers import write_demo_store, write_small_model

from vlaprobe.configs.finetune import FinetuneConfig


@pytest.fixture(scope="session")
def small_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_small_model(tmp_path_factory.mktemp("model") / "small")


@pytest.fixture(scope="session")
def demo_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    episodes = [(task, init, 24) for task in range(3) for init in range(4)]
    return write_demo_store(tmp_path_factory.mktemp("store") / "demos", episodes)


@pytest.fixture
def fast_cfg(small_model: Path, demo_store: Path, tmp_path: Path):
    """A config factory: a few steps of the small model on the demo store, one thread, no progress bar."""

    def make(**changes: object) -> FinetuneConfig:
        base = FinetuneConfig(
            stores=(demo_store,),
            out=tmp_path / "run",
            model=str(small_model),
            batch_size=8,
            max_steps=12,
            eval_every=4,
            warmup_steps=2,
            lr=2e-3,
            threads=1,
            progress=False,
            val_fraction=0.25,
        )
        return dataclasses.replace(base, **changes)

    return make
