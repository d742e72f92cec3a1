"""What `vlaprobe cognition` cannot do, said instead of failing: episodes whose goal no atom follows are left out
(named, with the reason), and probes without an action head run the cognition on the object head alone."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from tests.cognition.test_monitor import GOAL_STEP, KEYS, REGION, STEPS, write_run
from tests.probes.made import probes_for_report

from vlaprobe.cli import main as cli_main
from vlaprobe.cognition.monitor import MONITOR_FILE, monitor, read_monitor
from vlaprobe.configs.monitor import MonitorConfig
from vlaprobe.configs.report import ReportConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.pipeline import report


def test_an_episode_whose_goal_no_atom_follows_is_left_out_and_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store, probes = write_run(tmp_path, region_goals=(0,))
    argv = ["cognition", "--store", str(store), "--probes", str(probes), "--debounce", "1"]
    assert cli_main(argv) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"1 episode(s) left out, goal not followable: {KEYS[0]} (task 0): the goal ")
    assert f"should-move-towards({REGION})" in out[0]
    result = read_monitor(probes)
    assert result.episodes == 2 and [e.key for e in result.per_episode] == KEYS[1:]
    (skipped,) = result.skipped
    assert (skipped.key, skipped.task) == (KEYS[0], 0) and REGION in skipped.reason
    assert result.unknown_heads == [] and set(result.layers) == {"object", "action"}


def test_no_followable_episode_is_one_line(tmp_path: Path) -> None:
    store, probes = write_run(tmp_path, region_goals=(0, 1, 2))
    with pytest.raises(VlaprobeError, match="can follow none of the 3 episodes' goals") as exc:
        monitor(MonitorConfig(store=store, probes=probes, out=tmp_path / "out"))
    assert "\n" not in str(exc.value) and not (tmp_path / "out" / MONITOR_FILE).exists()


def test_probes_without_an_action_head_run_on_the_object_head_alone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store, probes = write_run(tmp_path, heads=("object",))
    assert cli_main(["cognition", "--store", str(store), "--probes", str(probes), "--debounce", "1"]) == 0
    assert (
        "the probes have no action head: the cognition ran on the other head alone" in capsys.readouterr().out
    )
    result = read_monitor(probes)
    assert result.unknown_heads == ["action"] and set(result.layers) == {"object"}
    # the relation alone marks the goal: episodes 0 and 1 reach it when the bowl rests on the plate, as truth does;
    # in episode 2 the probes never see it
    assert [e.goal_step_truth for e in result.per_episode] == [GOAL_STEP] * 3
    assert [e.goal_step_probes for e in result.per_episode] == [GOAL_STEP, GOAL_STEP, None]
    assert result.probes.goal_detection.recall == pytest.approx(2 / 3)
    assert result.steps == 3 * len(STEPS)


def test_the_report_says_what_the_cognition_left_out(tmp_path: Path) -> None:
    store, probes = write_run(tmp_path, region_goals=(0,), heads=("object",))
    monitor(MonitorConfig(store=store, probes=probes, out=tmp_path / "monitor"))
    report_probes = probes_for_report(tmp_path / "probes")
    (report_probes / MONITOR_FILE).write_bytes((tmp_path / "monitor" / MONITOR_FILE).read_bytes())
    page = report(ReportConfig(probes=report_probes, dpi=20)).read_text()
    start = page.index("<h2 id='cognition'>")
    html = page[start : page.index("<h2 id=", start + 1)]
    assert "object head at hidden state 1)" in html and "action head at" not in html
    assert "<strong>The probes have no action head</strong>" in html
    assert "<strong>1 episode(s) left out</strong>" in html and f"<td>{KEYS[0]}</td><td>0</td>" in html


def test_a_version_2_monitor_file_reads_with_nothing_left_out(tmp_path: Path) -> None:
    store, probes = write_run(tmp_path, region_goals=(0,))
    monitor(MonitorConfig(store=store, probes=probes, out=tmp_path))
    data = json.loads((tmp_path / MONITOR_FILE).read_text())
    assert data["skipped"] == [{"key": KEYS[0], "task": 0, "reason": data["skipped"][0]["reason"]}]
    old = {k: v for k, v in data.items() if k not in ("skipped", "unknown_heads")}
    (tmp_path / MONITOR_FILE).write_text(json.dumps({**old, "format_version": 2}))
    read = read_monitor(tmp_path)
    assert read.skipped == [] and read.unknown_heads == [] and read.episodes == 2
