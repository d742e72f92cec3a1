"""Every file in experiments/ parses into the run config, its sections merged over the run's defaults."""

from __future__ import annotations

from pathlib import Path

import pytest

from vlaprobe.cli import _load_config_file
from vlaprobe.configs.run import RunConfig

EXPERIMENTS = sorted((Path(__file__).parent.parent / "experiments").glob("*.yaml"))

# file name -> (suite, first_init, max_steps)
INTENDED = {
    "diverse.yaml": ("libero_spatial", 0, 300),
    "goal.yaml": ("libero_goal", 0, 450),
    "object.yaml": ("libero_object", 0, 300),
}


def test_every_experiment_is_listed() -> None:
    assert [p.name for p in EXPERIMENTS] == sorted(INTENDED)


@pytest.mark.parametrize("path", EXPERIMENTS, ids=lambda p: p.name)
def test_experiment_parses_with_intended_values(path: Path) -> None:
    cfg = _load_config_file(path, RunConfig)
    suite, first_init, max_steps = INTENDED[path.name]
    assert cfg.collect.env.suite == suite
    assert cfg.collect.first_init == first_init
    assert cfg.collect.env.max_steps == max_steps
    assert cfg.collect.episodes_per_task == 3
    assert cfg.out == Path("runs") / path.stem
    assert cfg.train.conditional  # the run's own default, not TrainConfig's


def test_sections_merge_over_the_run_defaults(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("collect:\n  workers: 1\n  env:\n    max_steps: 123\ntrain:\n  seed: 7\n")
    cfg = _load_config_file(path, RunConfig)
    default = RunConfig()
    assert cfg.collect.workers == 1 and cfg.collect.env.max_steps == 123 and cfg.train.seed == 7
    assert cfg.collect.first_init == default.collect.first_init == 40  # the run's default, not the class's 0
    assert cfg.collect.episodes_per_task == default.collect.episodes_per_task
    assert cfg.collect.env.suite == default.collect.env.suite
    assert cfg.train.conditional is True
