"""The command line: registry, config files, one-line errors."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from vlaprobe.cli import main
from vlaprobe.commands import COMMANDS
from vlaprobe.configs import config_from_dict, config_to_dict
from vlaprobe.configs.run import RunConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.pipeline import stage_configs


def test_every_command_target_resolves() -> None:
    import importlib

    for name, command in COMMANDS.items():
        module, func = command.target.split(":")
        assert callable(getattr(importlib.import_module(module), func)), name
        assert dataclasses.is_dataclass(command.config_class()), name


@pytest.mark.parametrize("name", list(COMMANDS))
def test_every_command_help_shows_config(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main([name, "--help"])
    assert exit_.value.code == 0
    assert "--config FILE" in capsys.readouterr().out


def test_config_equals_form_and_flags_override(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seen = []
    monkeypatch.setattr("vlaprobe.collection.info.info", lambda cfg: seen.append(cfg) or 0)
    path = tmp_path / "c.json"
    path.write_text(json.dumps({"path": "from/file", "json": True}))
    assert main(["info", f"--config={path}"]) == 0
    assert main(["info", "--config", str(path), "--no-json"]) == 0
    assert main(["info", "elsewhere", f"--config={path}"]) == 0
    assert [(str(c.path), c.json) for c in seen] == [
        ("from/file", True),
        ("from/file", False),
        ("elsewhere", True),
    ]


def test_unknown_command_is_named(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["monitr", "--help"]) == 2
    err = capsys.readouterr().err.strip()
    assert "unknown command 'monitr'" in err and "\n" not in err
    assert main(["--help"]) == 0 and "model-info" in capsys.readouterr().out


def test_monitor_is_a_deprecated_alias_of_cognition(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    seen = []
    monkeypatch.setattr("vlaprobe.cognition.monitor.main", lambda cfg: seen.append(cfg) or 0)
    argv = ["--store", str(tmp_path / "s"), "--probes", str(tmp_path / "p")]
    assert main(["cognition", *argv]) == 0
    assert capsys.readouterr().err == ""
    assert main(["monitor", *argv]) == 0
    assert capsys.readouterr().err == "vlaprobe: `vlaprobe monitor` is deprecated; use `vlaprobe cognition`\n"
    assert seen[0] == seen[1]
    assert "monitor" not in COMMANDS  # --help lists the new name only


def test_run_config_round_trips_through_json() -> None:
    cfg = RunConfig()
    cfg.collect.tasks = (0, 4)
    cfg.train.probe.max_iter = 7
    data = json.loads(json.dumps(config_to_dict(cfg)))
    assert config_from_dict(RunConfig, data) == cfg


ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    "path, command",
    [(p, "finetune") for p in sorted((ROOT / "recipes").glob("*.yaml"))]
    + [(p, "run") for p in sorted((ROOT / "experiments").glob("*.yaml"))],
    ids=lambda v: v.name if isinstance(v, Path) else v,
)
def test_shipped_config_files_parse(path: Path, command: str) -> None:
    """Every recipe (vlaprobe finetune) and experiment (vlaprobe run) in the repository loads through
    ``--config`` as its command's config: a renamed or retyped field shows here, not in a user's 60-minute run."""
    import yaml

    from vlaprobe.cli import _load_config_file

    cls = COMMANDS[command].config_class()
    cfg = _load_config_file(path, cls)
    assert isinstance(cfg, cls)
    assert {f.name for f in dataclasses.fields(cfg)} >= set(yaml.safe_load(path.read_text()))


def test_config_file_unknown_field_is_refused() -> None:
    with pytest.raises(VlaprobeError, match="unknown field"):
        config_from_dict(RunConfig, {"out": "x", "colect": {}})


@pytest.mark.parametrize(
    "data, where",
    [
        ({"train": {"store": 5}}, "train.store"),
        ({"train": {"probe": "notadict"}}, "train.probe"),
        ({"collect": {"driver": "bob"}}, "collect.driver"),
        ({"train": {"layers": [1, "a"]}}, "train.layers"),
        ({"train": {"layers": 5}}, "c.json"),
    ],
)
def test_config_file_wrong_types_are_one_line(data: dict, where: str) -> None:
    with pytest.raises(VlaprobeError, match=where) as err:
        config_from_dict(RunConfig, data, source="c.json")
    assert "\n" not in str(err.value)


def test_stage_paths_follow_the_run_folder(tmp_path: Path) -> None:
    cfg = stage_configs(RunConfig(out=tmp_path / "r"))
    assert cfg.collect.out == tmp_path / "r" / "activations"
    assert cfg.train.store == cfg.collect.out and cfg.train.out == tmp_path / "r" / "probes"
    assert cfg.report.probes == cfg.train.out and cfg.report.out == tmp_path / "r" / "report"


def test_missing_config_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--config", str(tmp_path / "nope.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("vlaprobe: error: config file not found") and "\n" not in err


def test_bad_config_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "c.json"
    bad.write_text('{"collect": {"episodes_per_task": "many"}}')
    assert main(["run", "--config", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert "episodes_per_task" in err and "\n" not in err


def test_info_on_a_non_store_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("vlaprobe: error:") and "\n" not in err


@pytest.mark.parametrize("flag", ["--suite", "--env.suite"])
def test_tasks_lists_the_suite_given(flag: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["tasks", flag, "libero_goal", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["task"] for r in rows] == list(range(10))
    assert rows[0]["instruction"] == "open the middle drawer of the cabinet"
    assert main(["tasks", flag, "libero_90", "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)) == 90


def test_suite_names_are_declared_once() -> None:
    from vlaprobe.configs.env import SUITES, EnvConfig

    assert SUITES == ("libero_spatial", "libero_object", "libero_goal", "libero_10", "libero_90")
    assert EnvConfig().suite == "libero_spatial"
    assert config_from_dict(EnvConfig, {"suite": "libero_10"}).suite == "libero_10"
    with pytest.raises(VlaprobeError, match="field 'suite' expects one of 'libero_spatial'"):
        config_from_dict(EnvConfig, {"suite": "libero_100"})
