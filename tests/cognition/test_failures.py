"""`vlaprobe failures` on synthetic episodes with known answers: a hidden state that carries the outcome is
found by the probe, the file round-trips through its one writer and reader, too few failures are refused."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from vlaprobe.cognition.failure_scores import FEATURES, EpisodeData
from vlaprobe.cognition.failures import evaluate, read_failures, write_failures
from vlaprobe.cognition.failures_report import table
from vlaprobe.configs.failures import FailuresConfig
from vlaprobe.errors import VlaprobeError


def episodes(n: int, seed: int = 0) -> list[EpisodeData]:
    """Half fail; a failure's hidden state drifts along one direction after its failure step, its progress
    stops at 0.5; every episode lasts 40-60 rows (lengths independent of the outcome)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        failed, length = i % 2 == 1, int(rng.integers(40, 61))
        step = int(rng.integers(5, 20)) if failed else None
        hidden = rng.normal(size=(length, 16)).astype(np.float32)
        progress = np.minimum(np.arange(length) / 30, 1.0)
        if failed:
            hidden[step:, 0] += 3.0
            progress = np.minimum(progress, 0.5)
        cols = np.zeros((length, len(FEATURES)))
        out.append(
            EpisodeData(f"e{i}", i % 3, failed, step, hidden, progress, cols, [()] * length, [""] * length)
        )
    return out


def test_probe_finds_the_failure_direction_and_the_figures_round_trip(tmp_path: Path) -> None:
    cfg = FailuresConfig(alpha=0.2, folds=3, bootstrap=100)
    result = evaluate(episodes(36), cfg, "truth", 3)
    by = {p.name: p for p in result.predictors}
    assert result.episodes == 36 and result.failed == 18 and result.known_failure_steps == 18
    assert by["probe"].auc["0.5"].value == 1.0 and by["cognition"].auc["1"].value == 1.0
    lstm = by["probe_lstm"].auc["1"].value  # the drift along one direction, read through the sequence model
    assert lstm is not None and lstm > 0.9
    assert by["time"].auc_at_step["25"].value == 0.5  # at one step, time alone cannot tell
    assert by["time"].auc_at_step["100"].value is None  # no episode runs that long
    assert by["probe"].auc_at_step["50"].value == 1.0
    time_auc = by["time"].auc["1"]
    assert time_auc.low is not None and time_auc.high is not None and time_auc.low < 0.5 + 0.3
    probe = by["probe"]
    assert probe.detection_rate.value is not None and probe.detection_rate.value > 0.8
    assert probe.lead_to_failure_step.value is not None and probe.lead_to_failure_step.value < 0
    assert probe.false_alarm_rate.value is not None and probe.false_alarm_rate.value <= 0.5
    assert sum(by["cognition"].alarm_drivers.values()) > 0 and not probe.alarm_drivers
    write_failures(tmp_path, result)
    assert read_failures(tmp_path) == result
    assert "probe" in table(result)


def test_the_mlp_probe_and_the_token_predictors_see_a_known_failure_signal(tmp_path: Path) -> None:
    """A failure's hidden state lies outside a sphere (no linear direction: only the MLP can find it); its
    action-token entropy rises after the failure step. ROC curves and bands come with the AUCs."""
    rng = np.random.default_rng(3)
    data = []
    for e in episodes(32, seed=3):
        norm = rng.normal(size=e.hidden.shape).astype(np.float32)
        norm /= np.linalg.norm(norm, axis=1, keepdims=True)
        radius = np.where(np.arange(e.length) >= (e.failure_step or e.length), 3.0, 1.0)[:, None]
        entropy = 1.0 + (np.arange(e.length) >= (e.failure_step or e.length))
        tokens = np.stack([entropy, 1 / entropy], 1)
        data.append(dataclasses.replace(e, hidden=norm * radius, tokens=tokens))
    result = evaluate(data, FailuresConfig(alpha=0.2, folds=2, bootstrap=50), "truth", 3)
    by = {p.name: p for p in result.predictors}
    assert set(by) == {
        "cognition",
        "probe",
        "probe_mlp",
        "probe_lstm",
        "time",
        "task_time",
        "token_entropy",
        "token_max_prob",
    }
    assert by["probe_mlp"].auc["1"].value is not None and by["probe_mlp"].auc["1"].value > 0.9
    assert (
        by["probe"].auc["1"].value is not None and by["probe"].auc["1"].value < by["probe_mlp"].auc["1"].value
    )
    assert by["token_entropy"].auc["1"].value == by["token_max_prob"].auc["1"].value == 1.0
    roc = by["token_entropy"].roc["1"]
    assert roc.fpr[0] == 0 and roc.tpr[-1] == 1 and np.isclose(np.trapezoid(roc.tpr, roc.fpr), 1.0)
    bands = by["token_entropy"].bands
    assert bands is not None and bands.success.median[-1] == 1.0 and bands.failure.median[-1] > 1.0
    write_failures(tmp_path, result)
    assert read_failures(tmp_path) == result
    no_tokens = evaluate(episodes(12), FailuresConfig(alpha=0.3, folds=2, bootstrap=5), "truth", 3)
    assert "token_entropy" not in {p.name for p in no_tokens.predictors}
    assert no_tokens.token_uncertainty.startswith("not scored") and no_tokens.token_match is None


def test_too_few_failures_are_refused() -> None:
    data = [e for e in episodes(20) if not e.failed] + [e for e in episodes(20) if e.failed][:2]
    with pytest.raises(VlaprobeError, match="2 failed and 10 successful episodes; --folds 5"):
        evaluate(data, FailuresConfig(), "truth", 3)


def test_a_damaged_file_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "failures.json").write_text('{"format": "vlaprobe-failures", "format_version": 1}')
    with pytest.raises(VlaprobeError, match="is damaged"):
        read_failures(tmp_path)


def test_the_command_on_a_written_store_with_and_without_probes(tmp_path: Path) -> None:
    """Failures stall at the carry (the cognition's stall and progress deficit see it) and run longer."""
    from tests.cognition.test_monitor import APPROACH, ATOMS, CARRY, PLACED, PLATE, arrays, write_run

    from vlaprobe.cognition.failures import main
    from vlaprobe.collection.store import EpisodeInfo
    from vlaprobe.collection.writer import StoreWriter

    _, probes = write_run(tmp_path / "run")  # probes that read the labels back from the hidden state
    meta = {
        "atom_names": ATOMS, "model_id": "fake", "model": {"model_id": "fake"}, "num_hidden_states": 2,
        "hidden_size": sum(len(v) for v in ATOMS.values()), "pooling": "last_prompt", "driver": "expert",
        "suite": "libero_spatial", "env": {}, "seed": 0,
    }  # fmt: skip
    rng = np.random.default_rng(0)
    with StoreWriter.open(tmp_path / "store", meta) as writer:
        for i in range(12):
            failed = i % 2 == 1
            steps = [APPROACH] * 5 + [CARRY] * (25 if failed else 6) + ([] if failed else [PLACED] * 4)
            y = np.array([np.concatenate(arrays(s)) for s in steps])
            x = (y * 2.0 - 1 + rng.normal(0, 0.1, y.shape)).astype(np.float16)
            info = EpisodeInfo(f"t00_i{i:02d}_a00", 0, i, 0, not failed, len(y), i, "expert")
            n = len(ATOMS["object"])
            cols = {"hidden": np.stack([x, x]), "object_atoms": y[:, :n], "action_atoms": y[:, n:]}
            attrs = {
                "goal": {"pick": "akita_black_bowl_1", "place": PLATE},
                "failure_step": 10 if failed else None,
            }
            writer.write_episode(info, cols, attrs)
    cfg = FailuresConfig(store=tmp_path / "store", out=tmp_path / "out", folds=2, alpha=0.3, bootstrap=50)
    with pytest.raises(
        VlaprobeError, match=r"--token-model tiny is tiny-openvla-seed0, but .* was observed by fake"
    ):
        main(dataclasses.replace(cfg, token_model="tiny"))  # another model than the store's observer
    assert not (tmp_path / "out" / "failures.json").exists()
    for extra in ({}, {"probes": probes}):
        assert main(dataclasses.replace(cfg, **extra)) == 0
        result = read_failures(tmp_path / "out")
        assert result.episodes == 12 and result.failed == 6 and result.known_failure_steps == 6
        assert result.atoms == ("truth" if not extra else str(probes)) and result.layer == 1
        cognition = next(p for p in result.predictors if p.name == "cognition")
        assert cognition.auc["1"].value == 1.0


@pytest.mark.parametrize(
    "args, message",
    [
        (["--alpha", "1.5"], "--alpha must be between 0 and 1, got 1.5"),
        (["--folds", "1"], "--folds needs at least 2"),
        (["--store", "nowhere"], "no activation store at nowhere"),
    ],
)
def test_bad_input_is_a_one_line_error(
    args: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from vlaprobe.cli import main as cli_main

    assert cli_main(["failures", "--out", str(tmp_path / "out"), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "out" / "failures.json").exists()


def test_the_report_shows_the_failures_section(tmp_path: Path) -> None:
    from tests.probes.made import probes_for_report

    from vlaprobe.cognition.failures_report import report_section
    from vlaprobe.configs.report import ReportConfig
    from vlaprobe.pipeline import report

    probes = probes_for_report(tmp_path / "probes")
    assert report_section(probes) is None
    result = evaluate(episodes(24), FailuresConfig(alpha=0.3, folds=2, bootstrap=20), "truth", 3)
    write_failures(probes, result)
    page = report(ReportConfig(probes=probes, dpi=20)).read_text()
    start = page.index("<h2 id='failures'>Failure prediction</h2>")
    html = page[start:]
    assert (
        html.count("<tr><td>") == 6  # one row per predictor
        and html.count("<figure><img") == 2
        and "ROC-AUC at 0.5" in html
        and "24 episodes" in html
    )


def test_undefined_atoms_feed_no_belief_to_the_cognitions_columns(tmp_path: Path) -> None:
    """A union store: the probes read an atom the episode leaves undefined (stored false) as true for 6 steps;
    the cognition's columns of that episode see no violation (without the mask, a left-right violation)."""
    from tests.cognition.test_monitor import FLICKER, write_run

    from vlaprobe.cognition.failures_load import load_episodes

    for undefined, violations in (None, {"left_right_converse"}), ({1: [FLICKER]}, set()):
        folder = tmp_path / ("union" if undefined else "spatial")
        store, probes = write_run(folder, undefined=undefined, flicker=6)
        data, source, _, _ = load_episodes(FailuresConfig(store=store, probes=probes, out=folder / "out"))
        assert source == str(probes) and len(data) == 3
        assert {r for step in data[1].rules for r in step} == violations
        assert data[1].cognition[:, 2].max() == len(violations)


def test_each_first_alarm_names_its_feature_rules_atoms_and_last_event(tmp_path: Path) -> None:
    """A failure's rows after its failure step hold a violation over on(a,b) and follow a regression: the
    cognition's first alarms name them, with the pending subgoal; the file (format 3) and the table carry them."""
    data = []
    for e in episodes(24):
        after = np.arange(e.length) >= (e.failure_step or e.length)
        rules = [("on_and_inside",) if a else () for a in after]
        atoms = [("on(a,b)",) if a else () for a in after]
        event = ["regression: grasped(a) no longer done" if a else "" for a in after]
        data.append(
            dataclasses.replace(
                e, rules=rules, subgoal=["grasped(a)"] * e.length, violated_atoms=atoms, last_event=event
            )
        )
    result = evaluate(data, FailuresConfig(alpha=0.3, folds=2, bootstrap=20), "truth", 3)
    cog = next(p for p in result.predictors if p.name == "cognition")
    failed_alarms = [c for c in cog.alarms if c.failed]
    assert failed_alarms and len(cog.alarms) == sum(
        v for k, v in cog.alarm_drivers.items() if not k.startswith("rule:")
    )
    late = [c for c in failed_alarms if c.rules]
    assert late and all(
        c.atoms == ["on(a,b)", "grasped(a)"] and c.event.startswith("regression") for c in late
    )
    assert all(c.atoms == ["grasped(a)"] and not c.event for c in cog.alarms if not c.rules)
    write_failures(tmp_path, result)
    assert read_failures(tmp_path) == result
    assert "alarm atoms {" in table(result) and "grasped(a)" in table(result)
