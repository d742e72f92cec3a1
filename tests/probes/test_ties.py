"""The set of layers tied with the best one, on synthetic curves whose answer is known."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vlaprobe.configs.train import TrainConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes import synthetic_data, train_on_data
from vlaprobe.probes.bootstrap import nan_percentiles
from vlaprobe.probes.evaluate import best_layer
from vlaprobe.probes.metrics import summarize
from vlaprobe.probes.results import EVALUATION_FILE, FORMAT_VERSION, READABLE_VERSIONS, read_evaluation
from vlaprobe.probes.ties import describe, layer_resamples, paired_differences, ranges, tie_set


def test_a_flat_curve_ties_every_layer() -> None:
    rng = np.random.default_rng(0)
    point = np.full(6, 0.8)
    shared = rng.normal(0, 0.03, size=(1000, 1))
    resampled = point + shared + rng.normal(0, 0.01, size=(1000, 6))
    assert tie_set(point, resampled, 2) == [0, 1, 2, 3, 4, 5]


def test_one_clear_peak_with_tight_resamples_is_alone() -> None:
    rng = np.random.default_rng(1)
    point = np.array([0.6, 0.62, 0.9, 0.61, 0.6])
    resampled = point + rng.normal(0, 0.005, size=(1000, 5))
    assert tie_set(point, resampled, 2) == [2]
    assert describe(2, [2]) == "best layer 2, no other layer tied with it"


def test_pairing_separates_layers_whose_own_intervals_overlap() -> None:
    rng = np.random.default_rng(2)
    point = np.array([0.80, 0.78])
    shared = rng.normal(0, 0.05, size=(1000, 1))  # resample-to-resample swings common to both layers
    resampled = point + shared + rng.normal(0, 0.003, size=(1000, 2))
    (low0, low1), (high0, high1) = nan_percentiles(resampled, (2.5, 97.5))
    assert low0 < high1 and low1 < high0  # unpaired: the two intervals overlap widely
    low, high = paired_differences(resampled, 0)
    assert 0 < low[1] < 0.02 < high[1]  # paired: the difference excludes 0
    assert tie_set(point, resampled, 0) == [0]
    # Independent resamples (no pairing) with the same spread would tie them.
    independent = point + rng.normal(0, 0.05, size=(1000, 2))
    assert tie_set(point, independent, 0) == [0, 1]


def test_undefined_layers_and_too_few_resamples() -> None:
    point = np.array([0.9, np.nan, 0.5])
    resampled = np.tile(point, (50, 1))
    assert tie_set(point, resampled, 0) == [0]  # NaN at the point: never tied; 0.4 below exactly: not tied
    few = np.full((50, 3), np.nan)
    few[0] = point
    assert tie_set(np.array([0.9, 0.8, 0.5]), few, 0) == [0, 1, 2]  # < 2 resamples: cannot be told apart


def test_layer_resamples_are_those_behind_the_layer_intervals() -> None:
    rng = np.random.default_rng(3)
    point = rng.random((4, 7))
    point[1, 3] = np.nan
    resampled = point + rng.normal(0, 0.05, size=(300, 4, 7))
    resampled[rng.random(resampled.shape) < 0.1] = np.nan
    layer = summarize(point, resampled, [np.arange(7)])["layer"]
    low, high = nan_percentiles(layer_resamples(point, resampled), (2.5, 97.5))
    np.testing.assert_allclose(low, layer["low"], atol=1e-12)
    np.testing.assert_allclose(high, layer["high"], atol=1e-12)


def test_ranges_and_description() -> None:
    assert ranges([27, 8, 9, 10, 12, 28]) == "8-10, 12, 27-28"
    assert ranges([]) == ""
    assert describe(30, [8, 9, 10, 11, 12, 27, 28, 29, 30, 31, 32]) == "best layer 30, tied with 8-12, 27-32"


def test_best_layer_records_the_set_as_hidden_state_indices() -> None:
    point = np.array([0.5, 0.9, 0.89, 0.6])
    resampled = point + np.random.default_rng(4).normal(0, 0.02, size=(500, 4))
    best = best_layer(point, point - 0.05, point + 0.05, [3, 5, 7, 9], "balanced_accuracy", resampled)
    assert (best.layer, best.index, best.tied) == (5, 1, [5, 7])
    alone = best_layer(point, point - 0.05, point + 0.05, [3, 5, 7, 9], "balanced_accuracy")
    assert alone.tied == [5]


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    data = synthetic_data(
        num_tasks=3, episodes_per_task=5, steps_per_episode=30, num_layers=5, hidden_size=32, signal=8.0
    )
    cfg = TrainConfig(bootstrap=200, auprc_bootstrap=0, shuffled_permutations=1, conditional=False)
    return train_on_data(data, cfg, tmp_path_factory.mktemp("ties"))


def test_evaluation_stores_the_tie_set(trained: Path) -> None:
    ev = read_evaluation(trained)
    assert ev.format_version == FORMAT_VERSION
    for h in ev.heads.values():
        assert h.best.layer in h.best.tied and h.best.tied == sorted(h.best.tied)
        assert set(h.best.tied) <= set(ev.layers) and h.best.tie_rule


def test_a_version_3_evaluation_still_reads_with_the_best_layer_alone(trained: Path, tmp_path: Path) -> None:
    data = json.loads((trained / EVALUATION_FILE).read_text())
    data["format_version"] = 3
    for h in data["heads"].values():
        del h["best"]["tied"], h["best"]["tie_rule"]
        del h["conditional_task"], h["conditional_task_time"]
        del h["families"], h["matched"], h["conditional_families"]
    (tmp_path / EVALUATION_FILE).write_text(json.dumps(data))
    ev = read_evaluation(tmp_path)
    for h in ev.heads.values():
        assert h.best.tied == [h.best.layer] and h.conditional() == {}


def test_a_newer_evaluation_is_refused_with_one_line(trained: Path, tmp_path: Path) -> None:
    data = json.loads((trained / EVALUATION_FILE).read_text())
    data["format_version"] = FORMAT_VERSION + 1
    (tmp_path / EVALUATION_FILE).write_text(json.dumps(data))
    readable = ", ".join(map(str, READABLE_VERSIONS))
    with pytest.raises(
        VlaprobeError,
        match=rf"format version {FORMAT_VERSION + 1}, this vlaprobe reads version\(s\) {readable}",
    ):
        read_evaluation(tmp_path)
