"""`vlaprobe run`'s control observer: where its store goes and how it reaches the probe training."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

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


def test_run_writes_the_headline_figures(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """`vlaprobe run` on fake episodes ends with ``results.json``, built from the files the run wrote."""
    from tests.collection.fakes import make_fake_worker

    import vlaprobe.collection.collect as collection
    from vlaprobe.configs.collect import CollectConfig
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.configs.train import TrainConfig
    from vlaprobe.pipeline import run
    from vlaprobe.results import RESULTS_FILE, read_results, results_from_run

    real_collect = collection.collect
    monkeypatch.setattr(collection, "collect", lambda cfg: real_collect(cfg, make_fake_worker))
    monkeypatch.setattr("vlaprobe.pipeline.check_run_suite", lambda cfg: None)  # the fake has no LIBERO suite
    collect = CollectConfig(
        tasks=(0, 1, 2), episodes_per_task=4, max_tries_per_task=12, progress=False,
        env=EnvConfig(max_steps=6, image_size=16),
    )  # fmt: skip
    cfg = RunConfig(
        out=tmp_path / "r", collect=collect, control_model="",
        train=TrainConfig(bootstrap=10, auprc_bootstrap=5, shuffled_control=False),
    )  # fmt: skip
    run(cfg)
    results = read_results(tmp_path / "r" / RESULTS_FILE)
    assert results == results_from_run(tmp_path / "r")
    assert results.figure("object.best.value") is not None and "cognition.goal.recall" in results.figures
    _report_refuses_the_runs_own(tmp_path / "r", capsys)


def _report_refuses_the_runs_own(run_folder: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`vlaprobe report` on a run's probes: refused over the run's own report, written with another --out."""
    from vlaprobe.cli import main

    page = run_folder / "report" / "index.html"
    before = page.read_bytes()
    probes = str(run_folder / "probes")
    for argv in (
        ["report", "--probes", probes],
        ["report", "--probes", probes, "--out", str(run_folder / "report")],
    ):
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "the report `vlaprobe run` wrote" in err and "pass --out" in err, err
    assert page.read_bytes() == before
    assert main(["report", "--probes", probes, "--out", str(run_folder / "report-2")]) == 0
    assert (run_folder / "report-2" / "index.html").is_file()


def test_a_finished_run_folder_can_be_run_again(tmp_path: Path) -> None:
    """Every file `vlaprobe run` writes is its own: the control observer's store and results.json too."""
    from vlaprobe.configs.checks import RUN_FOLDER
    from vlaprobe.files import check_owned_folder, mark_folder

    out = tmp_path / "r"
    for name in ("activations", "control", "probes", "report", "live"):
        (out / name).mkdir(parents=True)
    for name in ("config.json", "results.json"):
        (out / name).write_text("{}")
    mark_folder(out, RUN_FOLDER.owner)
    check_owned_folder(out, RUN_FOLDER)


def _fake_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, **collect_changes: object) -> RunConfig:
    """A `vlaprobe run` config on the fake simulator and model."""
    from tests.collection.fakes import make_fake_worker

    import vlaprobe.collection.collect as collection
    from vlaprobe.configs.collect import CollectConfig
    from vlaprobe.configs.env import EnvConfig

    real_collect = collection.collect
    monkeypatch.setattr(collection, "collect", lambda cfg: real_collect(cfg, make_fake_worker))
    monkeypatch.setattr("vlaprobe.pipeline.check_run_suite", lambda cfg: None)  # the fake has no LIBERO suite
    collect = CollectConfig(
        tasks=(0,), episodes_per_task=2, progress=False, env=EnvConfig(max_steps=6, image_size=16)
    )
    return RunConfig(
        out=tmp_path / "runs" / "r", collect=dataclasses.replace(collect, **collect_changes), control_model=""
    )


def test_a_refused_run_leaves_no_run_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from vlaprobe.errors import VlaprobeError
    from vlaprobe.pipeline import run

    cfg = _fake_run(tmp_path, monkeypatch, first_init=12)  # the fake tasks have 12 init states
    with pytest.raises(VlaprobeError, match="--first-init 12 leaves no init state"):
        run(cfg)
    assert list(tmp_path.iterdir()) == []


def test_a_second_run_into_the_same_folder_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from tests.test_locks import held

    from vlaprobe.errors import VlaprobeError
    from vlaprobe.pipeline import run

    cfg = _fake_run(tmp_path, monkeypatch)
    with held(cfg.out, "vlaprobe run --out r") as proc, pytest.raises(VlaprobeError) as err:
        run(cfg)
    assert f"is being written by pid {proc.pid} (vlaprobe run --out r)" in str(err.value)
    assert not cfg.out.exists()
