"""scripts/fit_check.py scores a checkpoint's validation rows as `vlaprobe finetune` did at its last step."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from vlaprobe.finetune.command import finetune

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "fit_check.py"


def test_fit_check_reproduces_the_runs_last_validation(fast_cfg, capsys: pytest.CaptureFixture[str]) -> None:
    spec = importlib.util.spec_from_file_location("fit_check", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    cfg = fast_cfg(max_steps=8, eval_every=8)
    assert finetune(cfg) == 0
    last = json.loads((cfg.out / "metrics.jsonl").read_text().splitlines()[-1])
    result = module.fit_check(str(cfg.out / "checkpoint"), cfg.stores, cfg.val_fraction, cfg.seed, 10_000)
    assert result["val"]["rows"] == last["val_samples"]
    assert result["val"]["accuracy"] == pytest.approx(last["val_accuracy"], abs=1e-9)
    assert result["val"]["l1"] == pytest.approx(last["val_l1"], rel=1e-6)
    assert 0 <= result["train"]["accuracy"] <= 1 and result["train"]["rows"] > 0
    assert "train: token accuracy" in capsys.readouterr().out
