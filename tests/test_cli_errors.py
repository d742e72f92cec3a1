"""Bad input and interruptions (issue #10): one line, exit 2, checked before any long work, nothing lost."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import pytest
from tests.collection.test_store import write

from vlaprobe.cli import main
from vlaprobe.configs.report import ReportConfig
from vlaprobe.configs.run import RunConfig
from vlaprobe.configs.train import ProbeConfig, SplitConfig, TrainConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.pipeline import run
from vlaprobe.probes import ProbeSet
from vlaprobe.probes import train as train_module
from vlaprobe.probes.outfolder import locked
from vlaprobe.probes.results import read_evaluation

FAST = dict(bootstrap=20, auprc_bootstrap=0, shuffled_permutations=1, probe=ProbeConfig(min_updates=5))


def one_line_error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("vlaprobe: error: ") and err.count("\n") == 1, err
    return err


@pytest.fixture
def store(tmp_path: Path) -> Path:
    path = tmp_path / "run" / "activations"
    write(path, [(0, 0, 6), (0, 1, 5), (0, 2, 6), (1, 0, 4), (1, 1, 7), (1, 2, 5)])
    return path


def folder_bytes(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


# ----- the probes folder is one unit ---------------------------------------------------------------------
def test_failed_final_write_keeps_the_old_probes_whole(
    store: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    out = store.parent / "probes"
    train_module.train_probes(TrainConfig(store=store, out=out, seed=1, **FAST))
    before = folder_bytes(out)

    def disk_full(self: ProbeSet, folder: Path) -> Path:  # the last file of the folder fails to write
        raise OSError(errno.ENOSPC, "No space left on device", str(folder / "probes.safetensors"))

    monkeypatch.setattr(ProbeSet, "save", disk_full)
    err = one_line_error(capsys, ["train", "--store", str(store), "--out", str(out), "--seed", "2"])
    assert "No space left on device" in err and "free some disk space" in err
    assert folder_bytes(out) == before  # config.json and evaluation.json of the failed run are not in it
    beside = sorted(p.name for p in out.parent.iterdir())
    assert beside == [".probes.lock", "activations", "probes"]  # no half-written folder beside it


def test_leftovers_of_a_killed_run_are_cleaned(store: Path) -> None:
    out = store.parent / "probes"
    (store.parent / ".probes.dead0001.partial").mkdir()
    out.mkdir()
    (out / ".probes.json.x1.tmp").write_text("{")
    (out / "probes.json").write_text("{}")  # a mix left by an older, in-place writer
    train_module.train_probes(TrainConfig(store=store, out=out, **FAST))
    assert not list(store.parent.glob(".probes.*.partial"))
    assert sorted(p.name for p in out.iterdir()) == [
        "config.json",
        "evaluation.json",
        "probes.json",
        "probes.safetensors",
    ]
    ProbeSet.load(out)
    read_evaluation(out)


def test_a_second_training_into_the_same_folder_is_refused(store: Path) -> None:
    out = store.parent / "probes"
    with locked(out), pytest.raises(VlaprobeError, match="being written by another `vlaprobe train`"):
        train_module.train_probes(TrainConfig(store=store, out=out, **FAST))


# ----- configs are written only when the stage succeeds ----------------------------------------------------
def test_rejected_run_keeps_the_run_config(store: Path) -> None:
    config = store.parent / "config.json"
    config.write_text('{"the": "last good run"}\n')
    cfg = RunConfig(out=store.parent)
    cfg.collect.policy.pooling = "mean_all"  # the store was collected with last_prompt
    with pytest.raises(VlaprobeError, match="pooling is"):
        run(cfg)
    assert config.read_text() == '{"the": "last good run"}\n'


def test_failing_train_keeps_the_probe_config(store: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = store.parent / "probes"
    train_module.train_probes(TrainConfig(store=store, out=out, **FAST))
    before = folder_bytes(out)
    for flag in (["--probe.lr", "inf"], ["--min-frequency", "nan"]):
        one_line_error(capsys, ["train", "--store", str(store), "--out", str(out), *flag])
    assert folder_bytes(out) == before


# ----- a folder holding something else is not written into --------------------------------------------------
def test_outputs_refuse_folders_holding_something_else(
    store: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run_folder = store.parent
    err = one_line_error(capsys, ["train", "--store", str(store), "--out", str(run_folder)])
    assert "holds other files than probes (activations)" in err
    err = one_line_error(capsys, ["save-tiny", "--out", str(store)])
    assert "holds other files" in err
    assert not (store / "model.safetensors").exists()


# ----- raw tracebacks become one line, before any work ------------------------------------------------------
TRAIN_RANGES = [
    (["--split.folds", "0"], "--split.folds must be at least 1"),
    (["--split.test-fraction", "0"], "--split.test-fraction must be a number in (0, 1)"),
    (["--split.test-fraction", "1.5"], "--split.test-fraction"),
    (["--probe.batch-size", "0"], "--probe.batch-size must be at least 1"),
    (["--probe.lr", "-1"], "--probe.lr must be a positive finite number"),
    (["--probe.lr", "nan"], "--probe.lr"),
    (["--probe.threshold", "1"], "--probe.threshold"),
    (["--probe.threshold", "0"], "--probe.threshold"),
    (["--min-frequency", "nan"], "--min-frequency"),
    (["--seed", "-1"], "--seed must be between 0"),
    (["--seed", str(2**70)], "--seed must be between 0"),
    (["--bootstrap", "-5"], "--bootstrap must be at least 0"),
    (["--probe.epochs", "0", "--probe.min-updates", "0"], "untrained probes"),
    (["--heads"], "--heads needs at least one head"),
    (
        ["--min-frequency", "0.5", "--max-frequency", "0.2"],
        "--min-frequency 0.5 must be below --max-frequency",
    ),
]


@pytest.mark.parametrize(("flags", "message"), TRAIN_RANGES)
def test_train_options_out_of_range(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flags: list[str], message: str
) -> None:
    # The store does not exist: the option must be refused before it is looked for.
    err = one_line_error(capsys, ["train", "--store", str(tmp_path / "none"), *flags])
    assert message in err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["collect", "--threads", "-2"], "--threads must be at least 1"),
        (["collect", "--env.max-steps", "0"], "--env.max-steps must be at least 1"),
        (["collect", "--env.image-size", "-5"], "--env.image-size must be at least"),
        (["collect", "--env.settle-steps", "-1"], "--env.settle-steps must be at least 0"),
        (["report", "--dpi", "0"], "--dpi must be between"),
        (["run", "--collect.episodes-per-task", "1"], "--collect.episodes-per-task 1 leaves no task with 2"),
        (["run", "--collect.tasks", "0", "1", "--train.split.folds", "9"], "--train.split.folds 9 needs"),
        (
            ["run", "--collect.workers", "0"],
            "--collect.workers must be at least 1",
        ),  # the prefix the user typed
        (["run", "--train.probe.lr", "inf"], "--train.probe.lr must be"),
        (["run", "--collect.tasks", "0", "99"], "--collect.tasks [99] do not exist"),
        (["run", "--train.split.folds", "31"], "--train.split.folds 31 needs at least that many episodes"),
        (["run", "--report.dpi", "-5"], "--report.dpi must be"),
        (["collect", "--first-init", "-1"], "--first-init must be at least 0"),
        (["save-tiny", "--patch-size", "13"], "--patch-size must divide the 224 px image"),
        (["run", "--control-model", "tiny", "--pooling", "action_tokens"], "--control-model needs"),
    ],
)
def test_collect_report_run_options_out_of_range(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    out = tmp_path / "out"
    err = one_line_error(capsys, [*argv, "--out", str(out)])
    assert message in err
    assert not out.exists()  # refused before anything was created


def test_no_task_with_two_episodes_is_one_line(tmp_path: Path) -> None:
    store = tmp_path / "s"
    write(store, [(0, 0, 6), (1, 0, 5), (2, 0, 6)])
    with pytest.raises(VlaprobeError, match="no task has 2 episodes"):
        train_module.train_probes(TrainConfig(store=store, **FAST))
    with pytest.raises(VlaprobeError, match=r"--split\.folds 4 needs at least 4 episodes"):
        train_module.train_probes(TrainConfig(store=store, split=SplitConfig(folds=4), **FAST))


@pytest.mark.parametrize("command", ["train", "collect", "report", "save-tiny", "run"])
def test_unwritable_outputs_fail_up_front(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("x")
    store = tmp_path / "none"
    extra = {"train": ["--store", str(store)], "report": ["--probes", str(store)]}.get(command, [])
    err = one_line_error(capsys, [command, *extra, "--out", str(a_file)])
    assert "is a file, not a folder" in err
    err = one_line_error(capsys, [command, *extra, "--out", str(a_file / "below")])
    assert f"{a_file} is a file, not a folder" in err
    err = one_line_error(capsys, [command, *extra, "--out", "/proc/vlaprobe-test"])
    assert "cannot write in /proc" in err


# ----- messages --------------------------------------------------------------------------------------------
def test_parse_errors_are_one_line_naming_the_flag_and_the_command_help(
    capsys: pytest.CaptureFixture[str],
) -> None:
    err = one_line_error(capsys, ["train", "--probe.lr", "abc"])
    assert "--probe.lr" in err and "see `vlaprobe train --help`" in err
    err = one_line_error(capsys, ["collect", "--no-such-flag"])
    assert "--no-such-flag" in err and "see `vlaprobe collect --help`" in err


def test_run_config_given_to_train_points_to_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from vlaprobe.configs import config_to_dict

    path = tmp_path / "config.json"
    path.write_text(json.dumps(config_to_dict(RunConfig())))
    err = one_line_error(capsys, ["train", "--config", str(path)])
    assert f"vlaprobe run --config {path}" in err


def test_empty_out_and_file_for_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert "--out got an empty value" in one_line_error(capsys, ["train", "--out", ""])
    assert "--out got an empty value" in one_line_error(capsys, ["save-tiny", "--out="])
    a_file = tmp_path / "file"
    a_file.write_text("x")
    assert "is a file, not a folder" in one_line_error(capsys, ["info", str(a_file)])
    assert "is a file, not a folder" in one_line_error(capsys, ["train", "--store", str(a_file)])
    assert "is a file, not a probe folder" in one_line_error(capsys, ["report", "--probes", str(a_file)])
    assert "is a folder, not a file" in one_line_error(capsys, ["train", "--config", str(tmp_path)])


def test_unknown_command_with_help_is_named(capsys: pytest.CaptureFixture[str]) -> None:
    assert "unknown command 'monitr'" in one_line_error(capsys, ["monitr", "--help"])


def test_report_refuses_before_writing(tmp_path: Path) -> None:
    with pytest.raises(VlaprobeError, match="--dpi"):
        from vlaprobe.reports.report import write_report

        write_report(ReportConfig(probes=tmp_path / "p", out=tmp_path / "r", dpi=-5))
    assert not (tmp_path / "r").exists()


def test_tiny_step_prints_no_deprecation(capfd: pytest.CaptureFixture[str]) -> None:
    import numpy as np
    from transformers.utils import logging as hf_logging

    from vlaprobe.policies.openvla.policy import OpenVLAPolicy

    hf_logging.get_logger("transformers").warning_once.cache_clear()  # shown once per process otherwise
    policy = OpenVLAPolicy.tiny(seed=0, device="cpu")
    policy.step(np.zeros((256, 256, 3), np.uint8), "put the bowl on the plate")
    assert "deprecated" not in capfd.readouterr().err


def test_files_helper_refuses_a_read_only_folder(tmp_path: Path) -> None:
    from vlaprobe.files import check_output_folder

    if os.geteuid() == 0:
        pytest.skip("root writes into read-only folders")
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o555)
    with pytest.raises(VlaprobeError, match="cannot write in"):
        check_output_folder(ro / "out")


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"hidden_size": "64"}, "LlamaDims.hidden_size must be a positive integer, got '64'"),
        ({"num_attention_heads": 7}, "is not a multiple of num_attention_heads 7"),
    ],
)
def test_bad_model_config_is_one_line(tmp_path: Path, change: dict, message: str) -> None:
    from vlaprobe.policies import load_policy
    from vlaprobe.policies.openvla.config import to_official
    from vlaprobe.policies.openvla.tiny import tiny_config

    official = to_official(tiny_config(), {})
    official["text_config"] = {**official["text_config"], **change}
    (tmp_path / "config.json").write_text(json.dumps(official))
    with pytest.raises(VlaprobeError, match=message) as err:
        load_policy(str(tmp_path), device="cpu")
    assert "\n" not in str(err.value)


def test_full_disk_is_found_before_training(store: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(1 << 30, 1 << 30, 1 << 20))
    trained = []
    monkeypatch.setattr(train_module, "train_on_data", lambda *a, **k: trained.append(1))
    with pytest.raises(VlaprobeError, match="1 MiB free on its disk, the probes need about"):
        train_module.train_probes(TrainConfig(store=store, out=store.parent / "probes", **FAST))
    assert not trained


def test_monitor_out_is_checked_first(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("x")
    argv = ["monitor", "--store", str(tmp_path / "none"), "--out", str(a_file)]
    assert f"--out {a_file} is a file, not a folder" in one_line_error(capsys, argv)  # not "no store"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["model-info", "--policy.seed", "-1"], "--policy.seed must be between 0"),
        (["model-info", "--policy.seed", str(2**70)], "--policy.seed must be between 0"),
        (["serve", "--seed", "-1"], "--seed must be between 0"),
        (["serve", "--seed", str(2**70)], "--seed must be between 0"),
        (
            ["serve", "--recordings", "/proc/vlaprobe-test"],
            "--recordings /proc/vlaprobe-test: cannot write in /proc",
        ),
        (["collect", "--tasks", "0", "99", "--out", "OUT"], "--tasks [99] do not exist"),
    ],
)
def test_seeds_recordings_and_tasks_are_checked_first(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    argv: list[str],
    message: str,
) -> None:
    from vlaprobe.policies import factory

    def no_model(*args: object) -> None:
        raise AssertionError("the options should be refused before any model is built")

    monkeypatch.setattr(factory, "make_policy", no_model)
    monkeypatch.setattr("vlaprobe.policies.openvla.commands.make_policy", no_model)
    if argv[0] == "serve":
        argv = [*argv, "--probes", str(tmp_path / "probes")]  # none there: the options fail first
    err = one_line_error(capsys, [str(tmp_path / "out") if a == "OUT" else a for a in argv])
    assert message in err
    assert not (tmp_path / "out").exists()


def test_serve_refuses_a_file_as_recordings(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("x")
    err = one_line_error(capsys, ["serve", "--probes", str(tmp_path / "none"), "--recordings", str(a_file)])
    assert f"--recordings {a_file} is a file, not a folder" in err


# ----- vlaprobe finetune (issue #17): refused in one line before any training ----------------------------
@pytest.fixture(scope="module")
def finetune_inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    from tests.finetune.helpers import write_demo_store, write_small_model

    root = tmp_path_factory.mktemp("finetune")
    return {
        "model": write_small_model(root / "model"),
        "wide_model": write_small_model(root / "wide", hidden_size=48),
        "store": write_demo_store(root / "demos", [(t, i, 6) for t in range(2) for i in range(3)]),
        "single": write_demo_store(root / "single", [(0, 0, 6), (1, 0, 6)]),
        "no_images": write_demo_store(root / "no_images", [(0, 0, 6), (0, 1, 6)], images=False),
    }


def _finetune_argv(inputs: dict[str, Path], out: Path, *extra: str, store: str = "store") -> list[str]:
    return [
        "finetune",
        "--stores",
        str(inputs[store]),
        "--model",
        str(inputs["model"]),
        "--out",
        str(out),
        *extra,
    ]


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--lr", "0"], "--lr must be a number above 0 and at most 1, got 0.0"),
        (["--lr", "nan"], "--lr must be a number above 0"),
        (["--lr", "30"], "--lr must be a number above 0 and at most 1, got 30.0"),
        (["--batch-size", "0"], "--batch-size must be at least 1, got 0"),
        (["--epochs", "0"], "--epochs must be at least 1, got 0"),
        (["--max-steps", "-3"], "--max-steps must be at least 1"),
        (["--val-fraction", "1"], "--val-fraction must be between 0 and 1"),
        (["--augment", "--freeze-vision"], "--augment needs the featurisers"),
        (["--batch-size", "64"], "fewer than --batch-size 64"),
    ],
)
def test_finetune_refuses_bad_settings(
    finetune_inputs: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    message: str,
) -> None:
    err = one_line_error(capsys, _finetune_argv(finetune_inputs, tmp_path / "out", *extra))
    assert message in err
    assert not (tmp_path / "out" / "checkpoint").exists()


@pytest.mark.parametrize(
    "store, message",
    [
        ("no_images", "has no images or actions"),
        ("single", "the validation split is empty"),
    ],
)
def test_finetune_refuses_stores_it_cannot_train_on(
    finetune_inputs: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    store: str,
    message: str,
) -> None:
    err = one_line_error(capsys, _finetune_argv(finetune_inputs, tmp_path / "out", store=store))
    assert message in err


def test_finetune_refuses_a_store_of_another_image_size(
    store: Path, finetune_inputs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = [
        "finetune",
        "--stores",
        str(store),
        "--model",
        str(finetune_inputs["model"]),
        "--out",
        str(tmp_path / "o"),
    ]
    assert "holds images of shape [8, 8, 3], the model takes 28x28x3" in one_line_error(capsys, argv)


def test_finetune_refuses_to_resume_another_shape_or_other_settings(
    finetune_inputs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    argv = _finetune_argv(finetune_inputs, out, "--max-steps", "1", "--batch-size", "4", "--threads", "1")
    assert main([*argv, "--no-progress"]) == 0
    capsys.readouterr()
    wide = [*argv[:4], str(finetune_inputs["wide_model"]), *argv[5:]]
    assert "holds a checkpoint of another model shape (text.hidden_size 32 vs 48)" in one_line_error(
        capsys, wide
    )
    assert "holds a run with other settings (lr 0.0005 vs 0.001)" in one_line_error(
        capsys, [*argv, "--lr", "1e-3"]
    )
    (out / "notes.txt").write_text("mine")
    assert "holds other files (notes.txt)" in one_line_error(capsys, argv)
