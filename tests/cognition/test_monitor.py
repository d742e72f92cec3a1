"""`vlaprobe cognition` on a store written by the collection's writer and probes that read the labels back."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from tests.cognition.scenes import APPROACH, BOWL2, CARRY, COOKIES, PLACED, PLATE, VOCAB, arrays
from tests.probes.made import evaluation_with_split, probes_for_report

from vlaprobe.cli import main as cli_main
from vlaprobe.cognition.monitor import (
    MONITOR_FILE,
    MONITOR_FORMAT_VERSION,
    EpisodeFigures,
    gain_interval,
    goal_detection,
    monitor,
    read_monitor,
    report_section,
)
from vlaprobe.collection.defined import defined_attrs
from vlaprobe.collection.store import EpisodeInfo
from vlaprobe.collection.writer import StoreWriter
from vlaprobe.configs.monitor import MonitorConfig
from vlaprobe.configs.report import ReportConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.pipeline import report
from vlaprobe.probes.probemeta import HeadMeta, ProbesMeta
from vlaprobe.probes.probeset import ProbeSet
from vlaprobe.probes.results import DroppedAtom, write_evaluation

SETTLING = frozenset({f"should-move-towards({PLATE})"})
STEPS = [APPROACH] * 6 + [CARRY] * 6 + [SETTLING] * 2 + [PLACED] * 6
GOAL_STEP = 14
FLICKER = f"left-of({BOWL2},{COOKIES})"
ATOMS = {"object": list(VOCAB.object_atoms), "action": list(VOCAB.action_atoms)}
SIZE = len(VOCAB.object_atoms) + len(VOCAB.action_atoms)
KEYS = ["t00_i00_a00", "t00_i01_a00", "t00_i02_a00"]
REGION = "main_table_stove_front_region"


def labels() -> np.ndarray:
    return np.array([np.concatenate(arrays(s)) for s in STEPS])


def write_run(
    root: Path,
    first_seed: int = 0,
    region_goals: tuple[int, ...] = (),
    heads: tuple[str, ...] = ("object", "action"),
    undefined: dict[int, list[str]] | None = None,
    flicker: int = 1,
    replayable: bool = False,
) -> tuple[Path, Path]:
    """Three episodes; the hidden state spells the labels (+-1), except where the probes should err. The episodes
    of ``region_goals`` record a goal onto a table region (no atom follows it); probes of ``heads`` only;
    ``undefined``: episode -> object atoms it leaves undefined (a union store's ``atoms_defined``); ``flicker``:
    steps the probes read the inconsistent atom as true in episode 1; ``replayable``: with the columns a replay
    reads (blank images, zero actions)."""
    meta = {
        "atom_names": ATOMS, "model_id": "fake", "model": {"model_id": "fake"}, "num_hidden_states": 2,
        "hidden_size": SIZE, "pooling": "last_prompt", "driver": "expert", "suite": "libero_spatial",
        "env": {}, "seed": 0,
    }  # fmt: skip
    n_obj = len(VOCAB.object_atoms)
    with StoreWriter.open(root / "store", meta) as writer:
        for e, key in enumerate(KEYS):
            y = labels()
            x = y.astype(np.float32) * 2 - 1
            if e == 1:  # a one-step flicker of an inconsistent atom
                x[3 : 3 + flicker, VOCAB.object_atoms.index(FLICKER)] = 1
            if e == 2:  # the probes never see the goal
                x[:, VOCAB.object_atoms.index(next(iter(PLACED)))] = -1
            hidden = np.stack([x, x]).astype(np.float16)
            info = EpisodeInfo(
                key=key,
                task=0,
                init=e,
                attempt=0,
                success=True,
                length=len(y),
                seed=first_seed + e,
                driver="expert",
            )
            arrays_ = {"hidden": hidden, "object_atoms": y[:, :n_obj], "action_atoms": y[:, n_obj:]}
            if replayable:
                actions = np.zeros((len(y), 7), np.float32)
                arrays_ |= {"image": np.zeros((len(y), 224, 224, 3), np.uint8), "action": actions}
                arrays_["predicted_action"] = actions
            place = REGION if e in region_goals else PLATE
            gone = defined_attrs(ATOMS, {"object": (undefined or {})[e]}) if e in (undefined or {}) else {}
            writer.write_episode(
                info, arrays_, {"goal": {"pick": "akita_black_bowl_1", "place": place}, **gone}
            )
    # probes: every atom that varies, the flicker atom, and one constant-true atom dropped at its majority
    y = labels()
    varying = set(np.flatnonzero(y.any(0) & ~y.all(0)).tolist()) | {VOCAB.object_atoms.index(FLICKER)}
    metas, tensors = {}, {}
    for h, offset in (("object", 0), ("action", n_obj)):
        if h not in heads:
            continue
        names = ATOMS[h]
        kept = [j for j in range(len(names)) if j + offset in varying]
        dropped = [
            DroppedAtom(names[j], float(y[:, j + offset].mean()), "rare")
            for j in range(len(names))
            if j not in kept
        ]
        w = torch.zeros(2, SIZE, len(kept))
        for c, j in enumerate(kept):
            w[:, j + offset, c] = 10.0
        tensors[f"{h}.weight"], tensors[f"{h}.bias"] = w, torch.zeros(2, len(kept))
        metas[h] = HeadMeta(atom_names=names, kept=[names[j] for j in kept], dropped=dropped, best_layer=1)
    pmeta = ProbesMeta(
        model_id="fake", pooling="last_prompt", hidden_size=SIZE, num_hidden_states=2, layers=[0, 1],
        threshold=0.5, heads=metas,
    )  # fmt: skip
    probes = ProbeSet(pmeta, tensors).save(root / "probes")
    write_evaluation(probes, evaluation_with_split(KEYS, model_id="fake", layers=[0, 1], hidden_size=SIZE))
    return root / "store", probes


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    return write_run(tmp_path_factory.mktemp("monitor"))


def test_monitor_compares_truth_and_probes(run: tuple[Path, Path]) -> None:
    store, probes = run
    result = monitor(MonitorConfig(store=store, probes=probes, debounce=1))
    assert (result.episodes, result.steps, result.held_out) == (3, 3 * len(STEPS), True)
    assert result.truth.violations_per_100_steps == 0 and set(result.truth.violations.values()) == {0}
    p = result.probes
    # the flicker; and in the episode whose goal the probes miss, no object to move towards after placing
    assert {r: n for r, n in p.violations.items() if n} == {"left_right_converse": 1, "towards_not_one": 1}
    assert p.violations_per_100_steps == pytest.approx(2 * 100 / (3 * len(STEPS)))
    g = p.goal_detection
    assert (g.precision, g.mean_delay_steps) == (1.0, 0.0) and g.recall == pytest.approx(2 / 3)
    assert (g.episodes, g.failed_episodes, g.false_alarms_per_100_steps) == (3, 0, 0.0)
    assert [e.goal_step_truth for e in result.per_episode] == [GOAL_STEP] * 3
    assert [e.goal_step_probes for e in result.per_episode] == [GOAL_STEP, GOAL_STEP, None]
    assert p.subgoal_accuracy == pytest.approx((3 * len(STEPS) - (len(STEPS) - GOAL_STEP)) / (3 * len(STEPS)))
    assert 0.95 < p.belief_agreement < 1
    # the bar: truth's step-0 state kept for the whole episode (the same labels in every episode here)
    y = labels()
    probed = sorted(set(np.flatnonzero(y.any(0) & ~y.all(0)).tolist()) | {VOCAB.object_atoms.index(FLICKER)})
    assert p.belief_agreement_step0 == pytest.approx((y[:, probed] == y[0, probed]).mean())
    assert p.belief_agreement_step0 < 0.9
    low, high = p.belief_agreement_gain_95
    assert 0 < low <= p.belief_agreement - p.belief_agreement_step0 <= high
    assert p.flips_per_step == p.flips_per_step_debounced > 0
    written = read_monitor(probes)
    assert written.probes.violations["left_right_converse"] == 1
    assert json.dumps(written.to_json()) == json.dumps(result.to_json())  # the round trip (NaN included)


def test_undefined_atoms_are_neither_believed_nor_scored(run: tuple[Path, Path], tmp_path: Path) -> None:
    """A union store: the flicker atom is undefined in episode 1 (stored false); the probes' one-step true there
    is no belief, no violation, no flip and no cell of the agreement. Elsewhere the figures are the spatial run's."""
    column = VOCAB.object_atoms.index(FLICKER)
    assert not labels()[:, column].any()  # stored as 0, as the writer stores an undefined atom
    store, probes = write_run(tmp_path, undefined={1: [FLICKER]})
    before = monitor(MonitorConfig(store=run[0], probes=run[1], debounce=1, out=tmp_path / "spatial"))
    after = monitor(MonitorConfig(store=store, probes=probes, debounce=1))
    assert {r: n for r, n in after.probes.violations.items() if n} == {"towards_not_one": 1}
    assert [e.violations_probes for e in after.per_episode] == [0, 0, 1]
    flip_steps = 3 * (len(STEPS) - 1)
    assert after.probes.flips_per_step * flip_steps == before.probes.flips_per_step * flip_steps - 2
    y = labels()
    probed = len(set(np.flatnonzero(y.any(0) & ~y.all(0)).tolist()) | {column})
    cells = 3 * len(STEPS) * probed
    agree = round(before.probes.belief_agreement * cells)  # the flicker's one disagreeing cell among them
    # episode 1's flicker column leaves the cells: its 19 agreeing steps and its one disagreeing step
    expected = (agree - (len(STEPS) - 1)) / (cells - len(STEPS))
    assert after.probes.belief_agreement == pytest.approx(expected)
    assert after.probes.belief_agreement > before.probes.belief_agreement


def test_monitor_file_versions(run: tuple[Path, Path], tmp_path: Path) -> None:
    """A newer or unknown monitor.json is refused with one line; a version-1 file (before false alarms) reads."""
    store, probes = run
    result = monitor(MonitorConfig(store=store, probes=probes, out=tmp_path))
    path = tmp_path / MONITOR_FILE
    data = json.loads(path.read_text())
    assert data["format_version"] == MONITOR_FORMAT_VERSION
    for change, match in (
        ({"format_version": MONITOR_FORMAT_VERSION + 1}, f"version {MONITOR_FORMAT_VERSION + 1}"),
        ({"format": "vlaprobe-evaluation"}, "not a vlaprobe monitor file"),
    ):
        path.write_text(json.dumps({**data, **change}))
        with pytest.raises(VlaprobeError, match=match) as exc:
            read_monitor(tmp_path)
        assert "\n" not in str(exc.value)
    old = {**data, "format_version": 1}  # what vlaprobe monitor wrote before false alarms were counted
    del old["probes"]["goal_detection"]["false_alarms_per_100_steps"]
    for e in old["per_episode"]:
        del e["false_alarms"]
    path.write_text(json.dumps(old))
    read = read_monitor(tmp_path)
    assert read.probes.goal_detection.false_alarms_per_100_steps is None and read.steps == result.steps


def test_debouncing_removes_the_flicker(run: tuple[Path, Path], tmp_path: Path) -> None:
    store, probes = run
    result = monitor(MonitorConfig(store=store, probes=probes, debounce=3, out=tmp_path))
    assert {r: n for r, n in result.probes.violations.items() if n} == {"towards_not_one": 1}
    assert result.probes.flips_per_step_debounced < result.probes.flips_per_step
    assert (tmp_path / MONITOR_FILE).is_file()


def test_cli_prints_the_figures_as_json(
    run: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store, probes = run
    assert (
        cli_main(
            ["cognition", "--store", str(store), "--probes", str(probes), "--out", str(tmp_path), "--json"]
        )
        == 0
    )
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(out) == {"episodes", "steps", "truth", "probes"}
    assert set(out["truth"]) == {"violations_per_100_steps", "violations"}
    assert set(out["probes"]) == {
        "violations_per_100_steps", "violations", "goal_detection", "subgoal_accuracy", "belief_agreement",
        "belief_agreement_step0", "belief_agreement_gain_95", "flips_per_step", "flips_per_step_debounced",
    }  # fmt: skip
    assert set(out["probes"]["goal_detection"]) == {
        "precision", "recall", "mean_delay_steps", "false_alarms_per_100_steps", "episodes", "failed_episodes",
    }  # fmt: skip


def test_the_report_shows_the_monitor_section(run: tuple[Path, Path], tmp_path: Path) -> None:
    """The section as the report renders it: a probe folder holding monitor.json gets the cognition section."""
    store, probes = run
    result = monitor(MonitorConfig(store=store, probes=probes, out=tmp_path / "monitor"))
    report_probes = probes_for_report(tmp_path / "probes")
    assert report_section(report_probes) is None  # no monitor.json: no section
    (report_probes / MONITOR_FILE).write_bytes((tmp_path / "monitor" / MONITOR_FILE).read_bytes())
    section = report_section(report_probes)  # what the report's section provider finds in a probe folder
    assert section is not None and section.id == "cognition" and section.data["steps"] == result.steps

    page = report(ReportConfig(probes=report_probes, dpi=20)).read_text()
    start = page.index("<h2 id='cognition'>Cognition: beliefs, rules and subgoals</h2>")
    html = page[start : page.index("<h2 id=", start + 1)]
    assert html.count("<table>") == 3 and all(rule in html for rule in result.truth.violations)
    assert f"({result.steps} steps)" in html and "held-out test" in html
    bar, (low, high) = result.probes.belief_agreement_step0, result.probes.belief_agreement_gain_95
    assert f"step-0 state (the bar)</td><td>{bar:.3f}</td>" in html and f"[{low:+.3f}, {high:+.3f}]" in html


@pytest.mark.parametrize(
    ("text", "words"),
    [(b"n(0). n(X+1) :- n(X).\n", "did not finish within 1 s: rule"), (b"\xff\n", "not UTF-8")],
)
def test_cognition_refuses_bad_rules_in_one_line(
    run: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str], text: bytes, words: str
) -> None:
    store, probes = run
    rules = tmp_path / "mine.lp"
    rules.write_bytes(text)
    argv = ["cognition", "--store", str(store), "--probes", str(probes), "--out", str(tmp_path / "out")]
    assert cli_main([*argv, "--rules", str(rules), "--budget.ground-seconds", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err and not (tmp_path / "out" / "monitor.json").exists()


def test_bad_input_is_a_one_line_error(
    run: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store, probes = run
    assert cli_main(["cognition", "--store", str(tmp_path / "none"), "--probes", str(probes)]) == 2
    assert cli_main(["cognition", "--store", str(store), "--probes", str(tmp_path)]) == 2
    bad = tmp_path / "bad.lp"
    bad.write_text("violation(x, A) :- lefty(A).\n")
    assert cli_main(["cognition", "--store", str(store), "--probes", str(probes), "--rules", str(bad)]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 3 and all(e.startswith("vlaprobe: error: ") for e in errors)
    assert f"{bad}:1:" in errors[2]


def test_goal_detection_on_succeeding_and_failing_episodes_has_known_figures() -> None:
    def ep(key: str, truth: int | None, probes: int | None, false_alarms: int = 0) -> EpisodeFigures:
        return EpisodeFigures(key, 100, truth, probes, false_alarms, 0, 0, 1.0)

    episodes = [
        ep("hit", 50, 53),  # both: delay 3
        ep("early", 60, 58),  # both: delay -2
        ep("missed", 70, None),  # a success the probes miss
        ep("alarm", None, 40, false_alarms=1),  # a failure the probes call a success
        ep("quiet", None, None),  # a failure, rightly never reached
    ]
    g = goal_detection(episodes)
    assert (g.precision, g.recall) == (pytest.approx(2 / 3), pytest.approx(2 / 3))
    assert g.mean_delay_steps == pytest.approx(0.5)
    assert g.false_alarms_per_100_steps == pytest.approx(100 * 1 / 500)
    assert (g.episodes, g.failed_episodes) == (5, 2)


def test_extra_stores_join_the_figures(run: tuple[Path, Path], tmp_path: Path) -> None:
    store, probes = run
    extra, _ = write_run(tmp_path / "more", first_seed=10)  # other episodes under the same keys
    result = monitor(MonitorConfig(store=store, probes=probes, extra_stores=(extra,), out=tmp_path))
    assert result.episodes == 6 == result.probes.goal_detection.episodes
    assert [e.key for e in result.per_episode][3:] == [
        f"{extra.name}/{e.key}" for e in result.per_episode[:3]
    ]


def test_extra_stores_that_repeat_episodes_are_refused(run: tuple[Path, Path], tmp_path: Path) -> None:
    store, probes = run
    copy = tmp_path / "copy"
    shutil.copytree(store, copy)
    for extra, words in (((store,), "trained on its episodes"), ((copy,), "trained on its episodes")):
        with pytest.raises(
            VlaprobeError,
            match=f"--extra-stores .* repeats 3 episode.s. of {re.escape(str(store))} .*{words}",
        ):
            monitor(MonitorConfig(store=store, probes=probes, extra_stores=extra, out=tmp_path / "out"))
    more, _ = write_run(tmp_path / "more", first_seed=10)
    with pytest.raises(VlaprobeError, match="counted twice"):
        monitor(MonitorConfig(store=store, probes=probes, extra_stores=(more, more), out=tmp_path / "out"))
    assert not (tmp_path / "out").exists()


def test_the_gain_interval_over_episodes_has_known_answers() -> None:
    cells = np.array([100, 200, 50])
    # every episode 0.9 against a bar of 0.8: every resample gains exactly 0.1
    low, high = gain_interval(0.9 * cells, 0.8 * cells, cells)
    assert low == pytest.approx(0.1) and high == pytest.approx(0.1)
    # one episode gains, one loses: the interval spans both and is ordered
    low, high = gain_interval(np.array([100, 0]), np.array([0, 100]), np.array([100, 100]))
    assert low == pytest.approx(-1.0) and high == pytest.approx(1.0)
    assert gain_interval(np.array([]), np.array([]), np.array([], dtype=int)) is None
