"""``results.json``: built from a run's real files, written and read back, refused when foreign; and the
README's Python example, run on the same small run."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from tests.collection.fakes import fake_probed_run

from vlaprobe.cognition.monitor import monitor
from vlaprobe.configs.monitor import MonitorConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.results import read_evaluation
from vlaprobe.results import (
    COGNITION_FIGURES,
    FORMAT_VERSION,
    HEAD_FIGURES,
    HEAD_LAYER_FIGURES,
    RESULTS_FILE,
    RUN_FIGURES,
    build_results,
    read_results,
    results_from_run,
    write_results,
)

README = Path(__file__).resolve().parent.parent / "README.md"


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run folder as ``vlaprobe run`` lays it out: fake episodes, probes trained on them, the cognition."""
    root = tmp_path_factory.mktemp("run")
    fake_probed_run(root)
    monitor(MonitorConfig(store=root / "activations", probes=root / "probes"))
    return root


def test_results_carry_the_evaluation_and_cognition_figures(run: Path) -> None:
    evaluation = read_evaluation(run / "probes")
    results = results_from_run(run)
    for head, h in evaluation.heads.items():
        assert results.figure(f"{head}.best.layer") == h.best.layer
        assert results.figure(f"{head}.best.value") == h.best.value
        assert (results.figure(f"{head}.best.low"), results.figure(f"{head}.best.high")) == (
            h.best.low,
            h.best.high,
        )
        assert h.task_time_baseline is not None
        tt = h.task_time_baseline[h.best.metric].layer
        assert results.figure(f"{head}.task_time_baseline.value") == tt.value[0]
        assert h.control is not None
        assert results.figure(f"{head}.shuffled.value") == h.control[h.best.metric].layer.value[h.best.index]
        assert results.figure(f"{head}.atoms") == len(h.atoms)
    assert results.figure("run.test_episodes") == evaluation.split.test.episodes
    cognition = json.loads((run / "probes" / "monitor.json").read_text())
    goal = cognition["probes"]["goal_detection"]
    assert results.figure("cognition.goal.recall") == goal["recall"]
    assert results.figure("cognition.episodes") == cognition["episodes"]
    # every figure is there, undefined ones as None (intervals as .value/.low/.high)
    roots = {
        k.rsplit(".", 1)[0] if k.rsplit(".", 1)[-1] in ("value", "low", "high") else k
        for k in results.figures
    }
    assert roots == {f"{h}.{k}" for h in evaluation.heads for k in (*HEAD_FIGURES, *HEAD_LAYER_FIGURES)} | {
        f"cognition.{k}" for k in COGNITION_FIGURES
    } | {f"run.{k}" for k in RUN_FIGURES}
    assert results.figure("object.control.best.value") is None  # this run had no control observer


def test_round_trip_through_the_one_writer_and_reader(run: Path, tmp_path: Path) -> None:
    results = results_from_run(run)
    path = write_results(tmp_path, results)
    assert path == tmp_path / RESULTS_FILE
    assert read_results(tmp_path) == results == read_results(path)
    cognition = monitor(MonitorConfig(store=run / "activations", probes=run / "probes", out=tmp_path / "m"))
    assert build_results(read_evaluation(run / "probes"), cognition) == results  # in-memory = from files


def test_foreign_newer_and_damaged_files_are_refused(run: Path, tmp_path: Path) -> None:
    path = write_results(tmp_path, results_from_run(run))
    data = json.loads(path.read_text())
    cases = {
        "format version 2": {**data, "format_version": FORMAT_VERSION + 1},
        "not a vlaprobe results file": {**data, "format": "other"},
        "damaged": {**data, "figures": "none"},
    }
    for message, content in cases.items():
        path.write_text(json.dumps(content))
        with pytest.raises(VlaprobeError, match=message):
            read_results(path)
    with pytest.raises(VlaprobeError, match="no "):
        read_results(tmp_path / "missing")
    with pytest.raises(VlaprobeError, match=r"no figure 'object\.nothing'"):
        results_from_run(run).figure("object.nothing")


def test_publish_copies_and_reports_changes(run: Path, tmp_path: Path) -> None:
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "publish_results", README.parent / "scripts" / "publish_results.py"
    )
    assert spec is not None and spec.loader is not None
    publish = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(publish)
    path, changed = publish.publish(run, "t", tmp_path)  # a run without results.json: read from its files
    assert read_results(path) == results_from_run(run) and changed
    assert publish.publish(run, "t", tmp_path)[1] == []  # the same run again: nothing changed
    with pytest.raises(VlaprobeError, match="not a folder"):
        publish.publish(tmp_path / "nope", "t", tmp_path)


def test_the_readme_python_example_runs(
    run: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    assert len(blocks) == 1, "the README has one Python example"
    code = blocks[0]
    assert len(code.strip().splitlines()) <= 7, "the README's example stays short"
    monkeypatch.chdir(run.parent)
    exec(compile(code.replace("runs/default", run.name), "README.md", "exec"), {})
    printed = capsys.readouterr().out
    assert printed.strip(), "the example prints the atoms it read"


@pytest.mark.parametrize("split", ["episode", "leave-one-task-out"])
def test_run_test_episodes_counts_every_scored_episode(tmp_path: Path, split: str) -> None:
    """``run.test_episodes`` is the number of episodes the figures pool (and resample), under every split:
    under leave-one-task-out every episode is held out once, not one fold's share."""
    from tests.collection.test_store import write

    from vlaprobe.configs.train import ProbeConfig, SplitConfig, TrainConfig
    from vlaprobe.probes.train import train_probes

    store = tmp_path / "activations"
    write(store, [(t, e, 5 + e) for t in range(3) for e in range(2)])
    probes = tmp_path / "probes"
    cfg = TrainConfig(
        store=store, out=probes, split=SplitConfig(by=split), bootstrap=5, auprc_bootstrap=0,
        shuffled_control=False, probe=ProbeConfig(c_grid=(0.1,), max_iter=50),
    )  # fmt: skip
    train_probes(cfg)
    ev = read_evaluation(probes)
    scored = len(set(ev.split.test_episodes))
    assert RUN_FIGURES["test_episodes"](ev) == scored
    if split == "leave-one-task-out":
        assert scored == 6 and ev.split.test.episodes == 2  # per fold: what results.json used to say
