"""Bad input and interruptions (issue #10): one line, exit 2, checked before any long work, nothing lost."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import pytest
from tests.collection.test_store import write

from vlaprobe.cli import main
from vlaprobe.configs.checks import REPORT_FOLDER
from vlaprobe.configs.report import ReportConfig
from vlaprobe.configs.run import RunConfig
from vlaprobe.configs.train import ProbeConfig, SplitConfig, TrainConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import check_owned_folder
from vlaprobe.pipeline import run
from vlaprobe.probes import ProbeSet
from vlaprobe.probes import train as train_module
from vlaprobe.probes.outfolder import locked
from vlaprobe.probes.results import read_evaluation

FAST = dict(
    bootstrap=20, auprc_bootstrap=0, shuffled_permutations=1, probe=ProbeConfig(c_grid=(0.1,), max_iter=50)
)


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
    assert beside == ["activations", "probes"]  # no half-written folder (nor lock file) beside it


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
    with locked(out), pytest.raises(VlaprobeError, match=f"is being written by pid {os.getpid()}"):
        train_module.train_probes(TrainConfig(store=store, out=out, **FAST))


def test_a_refused_training_leaves_nothing_behind(store: Path) -> None:
    out = store.parent / "new" / "probes"
    with pytest.raises(VlaprobeError, match="--shuffled-permutations must be at least 1"):
        train_module.train_probes(TrainConfig(store=store, out=out, **{**FAST, "shuffled_permutations": 0}))
    assert not out.parent.exists()  # neither the folder, its lock file nor the parent the lock made


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
    for flag in (["--probe.tol", "inf"], ["--min-frequency", "nan"]):
        one_line_error(capsys, ["train", "--store", str(store), "--out", str(out), *flag])
    assert folder_bytes(out) == before


def test_training_again_replaces_what_the_probes_other_commands_wrote(store: Path) -> None:
    from vlaprobe.configs.hypotheses import HypothesesConfig
    from vlaprobe.probes.hypotheses_run import hypotheses

    out = store.parent / "probes"
    train_module.train_probes(TrainConfig(store=store, out=out, **FAST))
    hypotheses(HypothesesConfig(probes=out))
    assert (out / "hypotheses.json").is_file()
    train_module.train_probes(TrainConfig(store=store, out=out, **FAST))  # the folder is still train's
    assert not (out / "hypotheses.json").exists()  # it described the replaced probes


# ----- a folder holding something else is not written into --------------------------------------------------
def test_outputs_refuse_folders_holding_something_else(
    store: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run_folder = store.parent
    err = one_line_error(capsys, ["train", "--store", str(store), "--out", str(run_folder)])
    assert "holds files `vlaprobe train` did not write (activations)" in err
    err = one_line_error(capsys, ["save-tiny", "--out", str(store)])
    assert "holds other files" in err
    assert not (store / "model.safetensors").exists()


# ----- raw tracebacks become one line, before any work ------------------------------------------------------
TRAIN_RANGES = [
    (["--split.folds", "0"], "--split.folds must be at least 1"),
    (["--split.test-fraction", "0"], "--split.test-fraction must be a number in (0, 1)"),
    (["--split.test-fraction", "1.5"], "--split.test-fraction"),
    (["--probe.max-iter", "0"], "--probe.max-iter must be at least 1"),
    (["--probe.tol", "-1"], "--probe.tol must be a positive finite number"),
    (["--probe.c-grid", "0.1", "nan"], "--probe.c-grid needs positive finite values"),
    (["--probe.c-grid", "0.1", "1", "--probe.cv-folds", "1"], "--probe.cv-folds must be at least 2"),
    (["--probe.threshold", "1"], "--probe.threshold"),
    (["--probe.threshold", "0"], "--probe.threshold"),
    (["--min-frequency", "nan"], "--min-frequency"),
    (["--seed", "-1"], "--seed must be between 0"),
    (["--seed", str(2**70)], "--seed must be between 0"),
    (["--bootstrap", "-5"], "--bootstrap must be at least 0"),
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
        (["run", "--train.probe.tol", "inf"], "--train.probe.tol must be"),
        (["run", "--collect.tasks", "0", "99"], "--collect.tasks [99] do not exist"),
        (["run", "--train.split.folds", "31"], "--train.split.folds 31 needs at least that many episodes"),
        (["run", "--report.dpi", "-5"], "--report.dpi must be"),
        (["collect", "--first-init", "-1"], "--first-init must be at least 0"),
        (["save-tiny", "--patch-size", "13"], "--patch-size must divide the 224 px image"),
        (["run", "--control-model", "tiny", "--pooling", "action_tokens"], "--control-model needs"),
        (["run", "--control-model", "tiny-libero"], "is the observed model itself"),
        (["run", "--train.probe.memory-mb", "-inf"], "--train.probe.memory-mb must be a positive finite"),
        (["train", "--probe.c-without-cv", "inf"], "--probe.c-without-cv must be a positive finite"),
        (["train", "--probe.c-without-cv", "0"], "--probe.c-without-cv must be a positive finite"),
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
    from vlaprobe.configs.policy import PolicyConfig
    from vlaprobe.policies import make_policy
    from vlaprobe.policies.openvla.config import to_official
    from vlaprobe.policies.openvla.tiny import tiny_config

    official = to_official(tiny_config(), {})
    official["text_config"] = {**official["text_config"], **change}
    (tmp_path / "config.json").write_text(json.dumps(official))
    with pytest.raises(VlaprobeError, match=message) as err:
        make_policy(PolicyConfig(str(tmp_path), device="cpu"))
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
    argv = ["cognition", "--store", str(tmp_path / "none"), "--out", str(a_file)]
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


# ----- issue 35: suites -------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["tasks", "--suite", "libero_100"],
            "invalid choice 'libero_100' for argument '--suite/--env.suite'",
        ),
        (["atoms", "--env.suite", "spatial"], "invalid choice 'spatial'"),
        (["model-info", "--suite", "libero_100"], "invalid choice 'libero_100'"),
        (
            ["atoms", "--suite", "libero_goal", "--task", "10"],
            "--task 10 out of range; libero_goal has tasks 0-9",
        ),
        (
            ["atoms", "--suite", "libero_90", "--task", "90"],
            "--task 90 out of range; libero_90 has tasks 0-89",
        ),
        (["atoms", "--init", "60"], "--init 60 does not exist; the task has init states 0-49"),
        (
            ["atoms", "--suite", "libero_10", "--init", "50"],
            "--init 50 does not exist; the task has init states 0-49",
        ),
        (  # the whole suite: the tasks without a skill named, the others selected
            ["collect", "--suite", "libero_90", "--out", "OUT"],
            "libero_90: the scripted expert has no skill for the goal conjunct of task 33 (Close(microwave_1)), "
            "task 35 (Open(microwave_1)); collect the others with --tasks 0 1 2 ",
        ),
        (  # the microwave's door has no skill
            ["collect", "--suite", "libero_10", "--tasks", "9", "--out", "OUT"],
            "libero_10 task 9: the scripted expert has no skill for the goal conjunct Close(microwave_1)",
        ),
        (
            ["collect", "--suite", "libero_goal", "--tasks", "5", "--perturb", "drop=0.5", "--out", "OUT"],
            "(a stove, a cabinet's top, a rack, a drawer); libero_goal task 5's goal is "
            "On(plate_1,main_table_stove_front_region): collect it without --perturb",
        ),
        (  # several conjuncts: the plan must end with a pick-and-place
            ["collect", "--suite", "libero_10", "--tasks", "0", "3", "--perturb", "drop=0.5", "--out", "OUT"],
            "libero_10 task 3's goal is Close(white_cabinet_1_bottom_region) & In(akita_black_bowl_1,white_cabinet_1"
            "_bottom_region): its plan ends with close white_cabinet_1_bottom_region, not with a pick-and-place: "
            "collect it without --perturb",
        ),
        (
            ["collect", "--suite", "libero_90", "--tasks", "0", "35", "--out", "OUT"],
            "libero_90 task 35: the scripted expert has no skill for the goal conjunct Open(microwave_1); leave "
            "it out of --tasks",
        ),
        (  # the policy drives, but a takeover hands over to the expert
            [
                "collect",
                "--suite",
                "libero_90",
                "--tasks",
                "33",
                "--driver",
                "policy",
                "--takeover",
                "random",
                "--out",
                "OUT",
            ],
            "libero_90 task 33: the scripted expert has no skill for the goal conjunct Close(microwave_1)",
        ),
        (
            ["collect", "--suite", "libero_90", "--tasks", "90", "--out", "OUT"],
            "--tasks [90] do not exist; libero_90 has tasks 0-89",
        ),
        (
            ["run", "--suite", "libero_90", "--out", "OUT"],
            "task 35 (Open(microwave_1)); collect the others with --collect.tasks 0 1 2 ",
        ),
        (
            ["run", "--suite", "libero_90", "--collect.tasks", "33", "--out", "OUT"],
            "libero_90 task 33: the scripted expert has no skill for the goal conjunct Close(microwave_1); leave "
            "it out of --collect.tasks",
        ),
    ],
)
def test_suite_inputs_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    argv = [str(tmp_path / "out") if a == "OUT" else a for a in argv]
    err = one_line_error(capsys, argv)
    assert message in err, err
    assert not (tmp_path / "out").exists()


# ----- issue 20: the inputs that still crashed or were silently accepted --------------------------------------
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["atoms", "--task", "²"], "--task '²' is neither a task index nor an instruction"),
        (["atoms", "--task", "①"], "neither a task index nor an instruction"),
        (["atoms", "--task", "0", "--env.image-size", "-5"], "--env.image-size must be at least 16"),
        (["atoms", "--env.settle-steps", "-1"], "--env.settle-steps must be at least 0"),
        (["atoms", "--init", "-1"], "--init must be at least 0"),
        (["atoms", "--init", "99"], "--init 99 does not exist; the task has init states 0-49"),
        (["atoms", "--init", str(2**70)], "--init must be at most 2147483647"),
        (["collect", "--env.image-size", "100000", "--out", "OUT"], "--env.image-size must be at most 4096"),
        (["train", "--probe.max-iter", str(2**70)], "--probe.max-iter must be at most 2147483647"),
        (["run", "--train.probe.device", "²", "--out", "OUT"], "--train.probe.device: unknown device '²'"),
        (["tasks", "--env.image-size", "-1"], "--env.image-size must be at least 16"),
        (["serve", "--port", "70000"], "--port must be between 0 and 65535"),
        (["serve", "--port", "-1"], "--port must be between 0 and 65535"),
        (["serve", "--max-message-bytes", "-1"], "--max-message-bytes must be at least 1024"),
        (["serve", "--replay-hz", "0.001"], "--replay-hz must be a number in [0.5, 60]"),
        (["serve", "--env.max-steps", "3000"], "--env.max-steps 3000 is more than the simulator runs"),
        (["serve", "--token-file", "NONE"], "is not a file"),
        (["collect", "--env.max-steps", "1200", "--out", "OUT"], "use at most 990"),
        (
            ["collect", "--env.max-steps", "995", "--env.settle-steps", "20", "--out", "OUT"],
            "use at most 980",
        ),
        (["run", "--collect.env.max-steps", "1200", "--out", "OUT"], "--collect.env.max-steps 1200 is more"),
    ],
)
def test_issue20_options_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    subst = {"OUT": str(tmp_path / "out"), "NONE": str(tmp_path / "none")}
    argv = [subst.get(a, a) for a in argv]
    if argv[0] == "serve":
        argv += ["--probes", str(tmp_path / "probes")]  # none there: the options fail first
    assert message in one_line_error(capsys, argv)
    assert not (tmp_path / "out").exists()


# ----- issue 39: --takeover with options that cannot go together --------------------------------------------
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["serve", "--takeover", "alarm"], "--driver expert has no policy; add --driver policy"),
        (["collect", "--takeover", "alarm", "--out", "OUT"], "add --driver policy or dagger"),
        (["run", "--takeover", "random", "--out", "OUT"], "add --collect.driver policy or dagger"),
        (
            ["serve", "--driver", "policy", "--takeover", "random", "--takeover-match", "OUT"],
            "--takeover-count",
        ),
        (["serve", "--driver", "policy", "--takeover", "alarm", "--takeover-probes", "OUT"], "its --probes"),
        (
            ["serve", "--driver", "policy", "--takeover", "alarm", "--takeover-stall", "0"],
            "--takeover-stall must",
        ),
        (
            ["serve", "--driver", "policy", "--takeover", "random", "--takeover-count", "0"],
            "--takeover-count must",
        ),
        (
            ["collect", "--driver", "policy", "--takeover", "alarm", "--takeover-steps", "0", "--out", "OUT"],
            "--takeover-steps must",
        ),
        (
            [
                *["collect", "--driver", "policy", "--takeover", "alarm"],
                "--takeover-on",
                "stall",
                "stall",
                "--out",
                "OUT",
            ],
            "--takeover-on names a kind twice",
        ),
        (["serve", "--driver", "policy", "--takeover", "alarm", "--takeover-on"], "--takeover-on"),
        (
            ["serve", "--driver", "policy", "--takeover", "alarm", "--takeover-on", "shake"],
            "--takeover-on",
        ),
    ],
)
def test_takeover_combinations_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    argv = [str(tmp_path / "out") if a == "OUT" else a for a in argv]
    if argv[0] == "serve":
        argv += ["--probes", str(tmp_path / "probes")]  # none there: the options fail first
    assert message in one_line_error(capsys, argv)
    assert not (tmp_path / "out").exists()


def test_config_files_that_crashed_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    binary = tmp_path / "c.json"
    binary.write_bytes(bytes(range(256)))
    assert "is not text" in one_line_error(capsys, ["train", "--config", str(binary)])
    bad = tmp_path / "c.yaml"
    bad.write_text("store: [1, 2\nout: 3\n")  # YAML's message spans several lines
    assert "cannot parse config file" in one_line_error(capsys, ["train", "--config", str(bad)])


def test_info_on_a_store_without_atom_names(store: Path, capsys: pytest.CaptureFixture[str]) -> None:
    meta = json.loads((store / "zarr.json").read_text())
    del meta["attributes"]["atom_names"]
    (store / "zarr.json").write_text(json.dumps(meta))
    assert "lacks atom_names" in one_line_error(capsys, ["info", str(store)])


def test_report_and_run_refuse_a_folder_of_someone_elses_files(
    store: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    probes = store.parent / "probes"
    train_module.train_probes(TrainConfig(store=store, out=probes, **FAST))
    mine = store.parent / "mine"
    mine.mkdir()
    (mine / "index.html").write_text("my page")
    (mine / "tables.json").write_text("{}")
    before = folder_bytes(mine)
    err = one_line_error(capsys, ["report", "--probes", str(probes), "--out", str(mine)])
    assert "holds files `vlaprobe report` did not write (index.html, tables.json)" in err
    err = one_line_error(capsys, ["run", "--out", str(mine)])
    assert "holds files `vlaprobe run` did not write" in err
    assert folder_bytes(mine) == before
    assert main(["report", "--probes", str(probes), "--out", str(store.parent / "report")]) == 0
    check_owned_folder(store.parent / "report", REPORT_FOLDER)  # its own folder: written again


@pytest.mark.parametrize("damage", ["missing object_atoms chunk", "corrupt hidden chunk"])
def test_monitor_refuses_a_damaged_store(
    store: Path, capsys: pytest.CaptureFixture[str], damage: str
) -> None:
    probes = store.parent / "probes"
    train_module.train_probes(TrainConfig(store=store, out=probes, **FAST))
    episodes = sorted(p for p in (store / "episodes").iterdir() if p.is_dir())
    array = "object_atoms" if "object" in damage else "hidden"
    chunks = [c for e in episodes for c in (e / array).rglob("*") if c.is_file() and c.name != "zarr.json"]
    if "missing" in damage:
        chunks[0].unlink()
    else:
        for c in chunks:
            c.write_bytes(b"not a chunk" * 8)
    argv = ["cognition", "--store", str(store), "--probes", str(probes), "--all-episodes"]
    err = one_line_error(capsys, argv)
    assert "damaged episode" in err and "rerun `vlaprobe collect`" in err


# ----- diverse data (#18): perturbation specs, sampled inits, cross-task split --------------------------------
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["collect", "--out", "OUT", "--perturb", "shake=0.5"], "--perturb: unknown perturbation 'shake'"),
        (
            ["collect", "--out", "OUT", "--perturb", "drop=1.5"],
            "drop needs a probability in [0, 1], got '1.5'",
        ),
        (
            ["collect", "--out", "OUT", "--perturb", "knock_off=-0.2"],
            "knock_off needs a probability in [0, 1]",
        ),
        (
            ["run", "--out", "OUT", "--collect.perturb", "displace"],
            "--collect.perturb: displace needs a probability",
        ),
    ],
)
def test_bad_perturbation_specs_are_refused_before_any_work(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    argv: list[str],
    message: str,
) -> None:
    from vlaprobe.policies import factory

    monkeypatch.setattr(
        factory, "make_policy", lambda *a: pytest.fail("no model before the options are checked")
    )
    err = one_line_error(capsys, [str(tmp_path / "out") if a == "OUT" else a for a in argv])
    assert message in err
    assert not (tmp_path / "out").exists()


def test_sampled_inits_of_a_task_whose_regions_cannot_be_sampled(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from vlaprobe.envs import libero

    real = libero.task_problem

    def unplaceable(task: int, suite: str = "libero_spatial") -> dict:
        problem = dict(real(task, suite))
        if task == 4:  # the bowl loses its (:init) placement
            problem["initial_state"] = [s for s in problem["initial_state"] if s[1] != "akita_black_bowl_1"]
        return problem

    monkeypatch.setattr(libero, "task_problem", unplaceable)
    out = tmp_path / "out"
    err = one_line_error(capsys, ["collect", "--out", str(out), "--tasks", "3", "4", "--inits", "sampled"])
    assert "--inits sampled: task 4's regions cannot be sampled (akita_black_bowl_1 has no On/In" in err
    assert "use --inits fixed" in err and not out.exists()
    # the same tasks pass the check with LIBERO's own BDDL files
    monkeypatch.setattr(libero, "task_problem", real)
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.envs.checks import check_inits

    check_inits(EnvConfig(inits="sampled"), ())


def test_leave_one_task_out_needs_two_tasks(store: Path, capsys: pytest.CaptureFixture[str]) -> None:
    one_task = store.parent / "one"
    write(one_task, [(0, 0, 6), (0, 1, 5), (0, 2, 6)])
    err = one_line_error(capsys, ["train", "--store", str(one_task), "--split", "leave-one-task-out"])
    assert "--split leave-one-task-out needs episodes of at least 2 tasks" in err


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
        (
            "single",
            "the validation split is empty: every task has fewer than 2 episodes; collect at least 2 episodes of some task (`vlaprobe collect --episodes-per-task 2`)",
        ),
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
    assert (
        "holds a run with other settings (--lr is 0.0005 in the folder but 0.001 in this run)"
        in one_line_error(capsys, [*argv, "--lr", "1e-3"])
    )
    (out / "notes.txt").write_text("mine")
    assert "holds other files (notes.txt)" in one_line_error(capsys, argv)


def test_swapped_inits_of_a_task_whose_instruction_cannot_be_checked(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from vlaprobe.envs import libero

    real = libero.suite_tasks

    def vague(suite: str = "libero_spatial") -> list[tuple[int, str]]:
        return [
            (i, "pick up the black bowl and place it on the plate" if i == 2 else t) for i, t in real(suite)
        ]

    monkeypatch.setattr(libero, "suite_tasks", vague)
    out = tmp_path / "out"
    err = one_line_error(
        capsys, ["collect", "--out", str(out), "--tasks", "1", "2", "--inits", "sampled-swap"]
    )
    assert (
        "--inits sampled-swap: task 2's instruction 'pick up the black bowl and place it on the plate'" in err
    )
    assert "use --inits sampled" in err and not out.exists()
