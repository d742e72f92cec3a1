"""`vlaprobe run`'s control observer: where its store goes and how it reaches the probe training."""

from __future__ import annotations

from pathlib import Path

from vlaprobe.configs.run import RunConfig
from vlaprobe.pipeline import control_store, stage_configs
from vlaprobe.policies.openvla.embedded import CONTROL_MODEL, DEFAULT_MODEL


def test_default_run_compares_the_trained_observer_with_the_random_one(tmp_path: Path) -> None:
    cfg = stage_configs(RunConfig(out=tmp_path / "r"))
    assert cfg.collect.policy.model == DEFAULT_MODEL and cfg.control_model == CONTROL_MODEL
    assert cfg.train.observer_store == control_store(cfg) == tmp_path / "r" / "control" / "activations"
    assert cfg.collect.first_init == 40  # scenes tiny-libero never saw in training


def test_empty_control_model_skips_the_control(tmp_path: Path) -> None:
    cfg = stage_configs(RunConfig(out=tmp_path / "r", control_model=""))
    assert cfg.train.observer_store is None
