"""The failure-prediction metrics on synthetic scores with known answers."""

from __future__ import annotations

import numpy as np
from sklearn.metrics import roc_auc_score

from vlaprobe.cognition import failure_metrics as fm
from vlaprobe.probes.bootstrap import bootstrap_weights, interval


def test_auc_matches_scikit_learn_with_ties_and_weights() -> None:
    rng = np.random.default_rng(0)
    scores = np.round(rng.normal(size=60), 1)  # ties
    failed = rng.random(60) < 0.4
    assert np.isclose(fm.weighted_auc(scores, failed), roc_auc_score(failed, scores))
    w = rng.integers(0, 4, 60).astype(float)
    expected = roc_auc_score(np.repeat(failed, w.astype(int)), np.repeat(scores, w.astype(int)))
    assert np.isclose(fm.weighted_auc(scores, failed, w), expected)
    assert np.isnan(fm.weighted_auc(scores, np.zeros(60, bool)))


def test_running_mean_time_and_alarms() -> None:
    assert np.allclose(fm.running_mean(np.array([1.0, 3.0, 2.0])), [1.0, 2.0, 2.0])
    curves = [np.arange(5.0), np.arange(11.0)]
    assert list(fm.at_time(curves, 0.5)) == [2.0, 5.0]
    assert list(fm.at_time(curves, 1.0)) == [4.0, 10.0]
    band = np.array([1.0, 1.0, 1.0, 1.0, 1.0])
    running = np.array([0.0, 2.0, 0.5, 3.0, 4.0])
    assert fm.first_alarm(running, band) == 1  # lead time to the end: 5 - 1 - 1 = 3 steps
    assert fm.alarm_onsets(running, band) == 2
    assert fm.first_alarm(np.zeros(5), band) is None
    assert fm.weighted_median(np.array([1.0, 5.0, 9.0]), np.array([0.0, 2.0, 1.0])) == 5.0


def test_conformal_band_controls_false_alarms_on_exchangeable_successes() -> None:
    """Calibration and test successes from one distribution: the share of test curves crossing the band
    is α up to its episode-bootstrap interval."""
    rng = np.random.default_rng(1)
    alpha, length = 0.1, 40

    def curves(n: int) -> list[np.ndarray]:
        return [fm.running_mean(rng.normal(0.1 * np.arange(length) / length, 1.0)) for _ in range(n)]

    band = fm.conformal_band(curves(199), alpha, length)
    crossed = np.array([fm.first_alarm(c, band) is not None for c in curves(400)], float)
    weights = bootstrap_weights(len(crossed), 1000, 0)
    low, high = interval(weights @ crossed / len(crossed))
    assert low <= alpha <= high
    assert 0.05 < crossed.mean() < 0.15


def test_conformal_band_is_infinite_without_enough_calibration() -> None:
    few = [np.zeros(5) for _ in range(5)]
    assert np.isinf(fm.conformal_band(few, 0.1, 5)).all()  # (5+1)·0.9 > 5
    assert np.isinf(fm.conformal_band([], 0.1, 5)).all()
    assert np.isfinite(fm.conformal_band([np.zeros(5) for _ in range(9)], 0.1, 5)).all()


def test_roc_curve_is_scikit_learns_and_its_area_is_the_auc() -> None:
    from sklearn.metrics import roc_curve

    rng = np.random.default_rng(1)
    scores = np.round(rng.normal(size=50), 1)  # ties
    failed = rng.random(50) < 0.5
    fpr, tpr = fm.roc_curve(scores, failed)
    ref_fpr, ref_tpr, _ = roc_curve(failed, scores, drop_intermediate=False)
    assert np.allclose(fpr, ref_fpr) and np.allclose(tpr, ref_tpr)
    assert fpr[0] == tpr[0] == 0 and fpr[-1] == tpr[-1] == 1
    assert np.isclose(np.trapezoid(tpr, fpr), fm.weighted_auc(scores, failed))
    assert fm.roc_curve(np.array([1.0, 0.0]), np.array([True, False])) == ([0.0, 0.0, 1.0], [0.0, 1.0, 1.0])
    assert fm.roc_curve(scores, np.zeros(50, bool)) == ([], [])


def test_score_bands_are_the_quartiles_at_each_normalised_time() -> None:
    curves = [np.full(11, float(v)) for v in (0, 1, 2, 3, 4)] + [np.arange(5.0) * 10]
    low, median, high = fm.score_bands(curves, [0.0, 1.0])
    assert median == [1.5, 2.5] and low == [0.25, 1.25] and high == [2.75, 3.75]
    assert fm.score_bands([], [0.5]) == ([], [], [])
