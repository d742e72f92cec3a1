"""The recipe of the observer trained on varied layouts (recipes/tiny-libero-diverse.yaml) loads and trains."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from vlaprobe.cli import _load_config_file
from vlaprobe.configs.finetune import FinetuneConfig
from vlaprobe.finetune.command import finetune

RECIPE = Path(__file__).resolve().parents[2] / "recipes" / "tiny-libero-diverse.yaml"


def test_the_diverse_recipe_trains_a_few_steps(fast_cfg) -> None:
    recipe = _load_config_file(RECIPE, FinetuneConfig)
    assert recipe.model_id == "tiny-libero-diverse" and recipe.max_minutes is not None  # resumable budget
    assert 0 < recipe.val_fraction < 1  # held-out episodes: sampled layouts never trained on
    # Its settings, on the tests' small model and store, for a few steps (the shape and paths are the run's).
    small = fast_cfg(max_steps=4, eval_every=2, warmup_steps=1)
    test_only = (
        "stores",
        "out",
        "model",
        "max_steps",
        "eval_every",
        "warmup_steps",
        "val_fraction",
        "progress",
    )
    cfg = dataclasses.replace(recipe, **{k: getattr(small, k) for k in test_only})
    assert finetune(cfg) == 0
    lines = [json.loads(x) for x in (cfg.out / "metrics.jsonl").read_text().splitlines()]
    assert [x["step"] for x in lines] == [2, 4]  # validated every eval_every steps, on held-out episodes
    assert all(0 <= x["val_accuracy"] <= 1 for x in lines)
