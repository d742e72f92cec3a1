"""A fine-tune's run folder: every defining setting is compared on resume, one writer at a time, and a refused
run leaves nothing behind."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest
from tests.test_locks import held

from vlaprobe.configs.finetune import FinetuneConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.finetune import model_io
from vlaprobe.finetune.checks import DEFINING, RUNTIME_FIELDS, check_run_folder
from vlaprobe.finetune.command import finetune, with_stores_suite
from vlaprobe.locks import lock_path


def _other(value: Any) -> Any:
    """A value of the same kind as ``value`` that differs from it."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value + 1
    if isinstance(value, float):
        return value + 0.125
    if isinstance(value, str):
        return value + "x"
    if isinstance(value, tuple):
        return (*value, 7)
    assert value is None
    return 3


def _snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    """(size, mtime) of every file in and beside ``folder`` but lock files (which a killed holder leaves)."""
    files = [p for p in folder.parent.rglob("*") if p.is_file() and p.suffix != ".lock"]
    return {str(p): (p.stat().st_size, p.stat().st_mtime_ns) for p in files}


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory, small_model: Path, demo_store: Path) -> FinetuneConfig:
    """A one-step fine-tune's settings, as the command resolves them (the statistics key from the stores' suite);
    its run folder holds a checkpoint to resume."""
    cfg = FinetuneConfig(
        stores=(demo_store,),
        out=tmp_path_factory.mktemp("finetune") / "run",
        model=str(small_model),
        batch_size=8,
        max_steps=1,
        warmup_steps=0,
        threads=1,
        progress=False,
        val_fraction=0.25,
    )
    assert finetune(cfg) == 0
    return with_stores_suite(cfg)[0]


def test_the_defining_settings_are_every_setting_but_the_runtime_ones() -> None:
    names = {f.name for f in dataclasses.fields(FinetuneConfig)}
    assert {s.key for s in DEFINING} == names - RUNTIME_FIELDS and len(DEFINING) > 20


@pytest.mark.parametrize("key", [s.key for s in DEFINING])
def test_a_resume_with_another_defining_setting_is_refused(finished: FinetuneConfig, key: str) -> None:
    arch = model_io.architecture(finished.model)
    assert check_run_folder(finished, arch)  # the same settings resume
    changed = dataclasses.replace(finished, **{key: _other(getattr(finished, key))})
    before = _snapshot(finished.out)
    with pytest.raises(VlaprobeError) as err:
        check_run_folder(changed, arch)
    label = "--" + key.replace("_", "-")
    assert f"holds a run with other settings ({label}" in str(err.value) and "in this run" in str(err.value)
    assert _snapshot(finished.out) == before


def test_a_second_finetune_on_the_folder_is_refused_with_the_holder(finished: FinetuneConfig) -> None:
    before = _snapshot(finished.out)
    with held(finished.out, "vlaprobe finetune --out run") as proc, pytest.raises(VlaprobeError) as err:
        finetune(finished)
    assert f"is being written by pid {proc.pid} (vlaprobe finetune --out run)" in str(err.value)
    assert _snapshot(finished.out) == before


def test_a_refused_finetune_leaves_nothing_behind(finished: FinetuneConfig, tmp_path: Path) -> None:
    out = tmp_path / "new" / "run"
    with pytest.raises(VlaprobeError, match="fewer than --batch-size 4096"):
        finetune(dataclasses.replace(finished, out=out, batch_size=4096))
    assert list(tmp_path.iterdir()) == [] and not lock_path(out).exists()
