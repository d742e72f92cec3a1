"""scripts/observer_table.py: the observers' table reads each figure from evaluation.json as written."""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path
from types import ModuleType

import pytest
import torch

from vlaprobe.configs.train import TrainConfig
from vlaprobe.probes import synthetic_data, train_on_data
from vlaprobe.probes.results import arr, read_evaluation

SCRIPT = Path(__file__).parents[2] / "scripts" / "observer_table.py"


def _script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("observer_table", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def probes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    data = synthetic_data(
        num_tasks=3, episodes_per_task=5, steps_per_episode=30, num_layers=3, hidden_size=16
    )
    noise = torch.randn(data.hidden.shape, generator=torch.Generator().manual_seed(0)).to(data.hidden.dtype)
    control = dataclasses.replace(data, hidden=noise, model_id="untrained")
    cfg = TrainConfig(bootstrap=50, auprc_bootstrap=0, shuffled_permutations=2, conditional=True)
    return train_on_data(data, cfg, tmp_path_factory.mktemp("probes"), observer=control)


def test_rows_quote_the_evaluation(probes: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _script().main([f"a={probes}", f"b={probes}"]) == 0
    out = capsys.readouterr().out
    evaluation = read_evaluation(probes)
    for head, h in evaluation.heads.items():
        assert f"\n{head} head\n" in out
        row = next(
            line for line in out.splitlines() if line.startswith("| a |") and f"{h.best.value:.3f}" in line
        )
        assert f"{h.best.layer} {{" in row
        tt = h.task_time_baseline["balanced_accuracy"].layer  # type: ignore[index]
        assert f"{float(arr(tt.value).reshape(-1)[0]):.3f}" in row
        assert h.control is not None and h.selectivity is not None
        i = h.best.index
        for part in (h.control, h.selectivity):
            assert f"{float(arr(part['balanced_accuracy'].layer.value)[i]):.3f}" in row
        assert h.families
        families = h.conditional_families["task_time"]
        for j, family in enumerate(h.families):
            at_best = float(arr(families.value)[i, j])
            if at_best == at_best:  # a family whose atoms are all undefined has no row
                frow = next(line for line in out.splitlines() if line.startswith(f"| a | {family} |"))
                assert f"{at_best:+.3f}" in frow
        gain = h.conditional_task_time
        assert gain is not None and f"{float(arr(gain.gain.value).max()):.3f}" in row


def test_bad_arguments_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _script().main([str(tmp_path)]) == 2
    assert _script().main([f"a={tmp_path}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("observer_table: ") for line in err)
