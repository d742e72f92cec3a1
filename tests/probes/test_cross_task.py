"""Leave-one-task-out: one fold per task, no step of the held-out task in training, every episode tested once."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from tests.probes.made import evaluation_with_split, head_result

from vlaprobe.configs.train import SplitConfig, TrainConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes import synthetic_data, train_on_data
from vlaprobe.probes.results import write_evaluation
from vlaprobe.probes.split import check_no_leak, leave_one_task_out, make_folds, rows_of


def test_each_fold_tests_one_task_and_trains_on_all_others_without_a_leak() -> None:
    tasks = np.repeat([0, 1, 2, 5], [3, 2, 4, 1])
    folds = leave_one_task_out(tasks)
    assert len(folds) == 4
    episode = np.repeat(np.arange(len(tasks)), 7)  # 7 steps per episode
    for fold, task in zip(folds, [0, 1, 2, 5], strict=True):
        assert set(tasks[fold.test]) == {task} and task not in set(tasks[fold.train])
        assert len(fold.train) + len(fold.test) == len(tasks)
        train_rows, test_rows = rows_of(episode, fold.train), rows_of(episode, fold.test)
        check_no_leak(episode, train_rows, test_rows)
        assert not set(tasks[episode[train_rows]]) & set(tasks[episode[test_rows]])
    assert sorted(np.concatenate([f.test for f in folds]).tolist()) == list(range(len(tasks)))
    with pytest.raises(VlaprobeError, match="at least 2 tasks"):
        make_folds(np.zeros(4, np.int64), SplitConfig(by="leave-one-task-out"), 0)


def test_training_with_leave_one_task_out_tests_every_episode_in_its_tasks_fold(tmp_path: Path) -> None:
    data = synthetic_data(
        num_tasks=3,
        episodes_per_task=3,
        steps_per_episode=20,
        num_layers=3,
        hidden_size=16,
        num_object=10,
        num_action=3,
        signal=8.0,
        seed=2,
    )
    cfg = TrainConfig(
        split=SplitConfig(by="leave-one-task-out"), bootstrap=50, auprc_bootstrap=0, shuffled_control=False
    )
    out = train_on_data(data, cfg, tmp_path)
    ev = json.loads((out / "evaluation.json").read_text())
    assert ev["split"]["folds"] == 3
    assert sorted(ev["split"]["test_episodes"]) == sorted(data.episode_keys)
    best = ev["heads"]["object"]["best"]
    assert best["value"] > 0.6  # the synthetic signal is shared by all tasks: it transfers


def _evaluation(
    folder: Path, best: int, values: list[list[float]], predicates: list[str], **changes: object
) -> Path:
    """A probe folder whose evaluation.json (written by write_evaluation) has these per-predicate figures."""
    layers = list(range(len(values)))
    head = head_result(predicates, values, best, layers)
    ev = evaluation_with_split(["e0"], layers=layers, heads={"object": head})
    write_evaluation(folder, dataclasses.replace(ev, **changes))
    return folder


def _by(split: str) -> dict:
    return {"split": {"by": split}}


@pytest.mark.parametrize(
    ("within", "across", "words"),
    [
        ("episode", "leave-one-task-out", None),
        ("leave-one-task-out", "episode", "the folders are swapped"),
        ("episode", "episode", "both trained with --split.by episode"),
    ],
)
def test_the_two_folders_must_be_a_within_and_a_cross_task_pair(
    tmp_path: Path, within: str, across: str, words: str | None
) -> None:
    from vlaprobe.probes.cross_task import split_comparison

    w = _evaluation(tmp_path / "w", 0, [[0.9]], ["on"], config=_by(within))
    a = _evaluation(tmp_path / "a", 0, [[0.7]], ["on"], config=_by(across))
    if words is None:
        assert split_comparison(w, a)[0].drop == pytest.approx(0.2)
        with pytest.raises(VlaprobeError, match="the same folder"):
            split_comparison(w, tmp_path / "a" / ".." / "w")
        return
    with pytest.raises(VlaprobeError, match=words):
        split_comparison(w, a)


def test_folders_of_another_model_or_store_are_refused(tmp_path: Path) -> None:
    from vlaprobe.probes.cross_task import split_comparison

    w = _evaluation(tmp_path / "w", 0, [[0.9]], ["on"])
    other = _evaluation(tmp_path / "m", 0, [[0.7]], ["on"], model_id="other")
    with pytest.raises(VlaprobeError, match=r"different data \(model 'fake' vs 'other'"):
        split_comparison(w, other)
    ev = evaluation_with_split(["e0"])
    fewer = _evaluation(
        tmp_path / "d", 0, [[0.7]], ["on"], dataset=dataclasses.replace(ev.dataset, episodes=1)
    )
    with pytest.raises(VlaprobeError, match="different data"):
        split_comparison(w, fewer)


def test_folders_of_two_suites_are_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from vlaprobe.cli import main

    w = _evaluation(tmp_path / "w", 0, [[0.9]], ["on"], config=_by("episode"))
    a = _evaluation(tmp_path / "a", 0, [[0.7]], ["on"], config=_by("leave-one-task-out"), suite="libero_goal")
    assert main(["compare-splits", "--within", str(w), "--across", str(a)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert (
        f"--within {w} is from libero_spatial, --across {a} from libero_goal; combine artefacts of one suite"
        in err
    )


@pytest.mark.parametrize("text", ["{}", "", "[1]", '{"format": "vlaprobe-evaluation", "format_version": 4}'])
def test_an_empty_or_malformed_evaluation_is_one_line(tmp_path: Path, text: str) -> None:
    from vlaprobe.cli import main

    w = _evaluation(tmp_path / "w", 0, [[0.9]], ["on"])
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "evaluation.json").write_text(text)
    assert main(["compare-splits", "--within", str(w), "--across", str(tmp_path / "a")]) == 2


def test_split_comparison_reads_each_folder_at_its_best_layer(tmp_path: Path) -> None:
    from vlaprobe.probes.cross_task import split_comparison

    within = _evaluation(tmp_path / "w", 1, [[0.6, 0.7], [0.9, 0.8]], ["left-of", "on"])
    across = _evaluation(tmp_path / "a", 0, [[0.65, 0.55, 0.5], [0.1, 0.1, 0.1]], ["left-of", "on", "inside"])
    rows = split_comparison(within, across)
    assert [(r.predicate, r.within, r.across) for r in rows] == [
        ("left-of", 0.9, 0.65),
        ("on", 0.8, 0.55),
        ("inside", None, 0.5),
    ]
    assert rows[0].drop == pytest.approx(0.25) and rows[2].drop is None
    assert rows[1].within_interval == (pytest.approx(0.75), 0.8)
