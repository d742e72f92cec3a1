"""The episode bootstrap: resampling weights, the percentile interval and its missing-value convention."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from vlaprobe.probes.bootstrap import (
    bootstrap_weights,
    interval,
    nan_mean,
    nan_percentiles,
    nan_std,
    percentile_interval,
    resample_sums,
)


def test_bootstrap_weights_resample_whole_groups() -> None:
    w = bootstrap_weights(7, 50, seed=0)
    assert w.shape == (50, 7)
    assert np.all(w.sum(1) == 7)
    assert np.array_equal(w, bootstrap_weights(7, 50, seed=0))
    assert not np.array_equal(w, bootstrap_weights(7, 50, seed=1))


def test_the_first_resamples_do_not_depend_on_how_many_are_drawn() -> None:
    # vlaprobe train draws max(bootstrap, auprc_bootstrap) and scores counts on the first `bootstrap`;
    # vlaprobe hypotheses draws `bootstrap` with the same seed: the same resamples
    for groups in (2, 10, 33):
        np.testing.assert_array_equal(
            bootstrap_weights(groups, 1000, 13)[:137], bootstrap_weights(groups, 137, 13)
        )


def test_each_group_is_drawn_with_probability_one_over_groups() -> None:
    w = bootstrap_weights(4, 20000, seed=2)
    np.testing.assert_allclose(w.mean(0), 1.0, atol=0.03)  # multinomial(4, 1/4): mean 1, variance 3/4
    np.testing.assert_allclose(w.var(0), 0.75, atol=0.03)


def test_resample_sums_weight_each_group() -> None:
    w = np.array([[2.0, 0, 1], [0, 0, 3]])
    per_group = np.arange(3 * 2 * 4, dtype=float).reshape(3, 2, 4)
    got = resample_sums(w, per_group)
    np.testing.assert_array_equal(got[0], 2 * per_group[0] + per_group[2])
    np.testing.assert_array_equal(got[1], 3 * per_group[2])
    np.testing.assert_array_equal(resample_sums(w, np.array([1.0, 10, 100])), [102.0, 300.0])


def test_interval_of_a_known_distribution() -> None:
    # resamples 0, 1, ..., 1000: the 2.5th and 97.5th percentiles are 25 and 975 exactly
    low, high = interval(np.random.default_rng(0).permutation(np.arange(1001.0)))
    assert (low, high) == (25.0, 975.0)
    # the bootstrap of a mean of 400 standard normal episodes: about +-1.96 / sqrt(400)
    rng = np.random.default_rng(1)
    x = rng.standard_normal(400)
    means = resample_sums(bootstrap_weights(400, 4000, seed=3), x) / 400
    low, high = interval(means)
    assert low == pytest.approx(x.mean() - 1.96 / 20, abs=0.012)
    assert high == pytest.approx(x.mean() + 1.96 / 20, abs=0.012)


def test_missing_values_are_left_out_and_two_are_needed() -> None:
    x = np.array([[1.0, np.nan, np.nan], [3.0, 5.0, np.nan], [np.nan, 7.0, np.nan], [2.0, np.nan, 4.0]])
    low, high = percentile_interval(x)
    want = np.percentile([1.0, 3.0, 2.0], [2.5, 97.5])
    assert low[0] == pytest.approx(want[0]) and high[0] == pytest.approx(want[1])
    assert low[1] == pytest.approx(5.05) and high[1] == pytest.approx(6.95)  # 5 and 7 only
    assert np.isnan(low[2]) and np.isnan(high[2])  # one defined resample: no interval
    assert all(np.isnan(v) for v in interval(np.array([0.5])))  # one resample: none
    assert all(np.isnan(v) for v in interval(np.full(10, np.nan)))


def test_nan_mean_and_std_leave_out_undefined_entries() -> None:
    x = np.array([[1.0, np.nan], [3.0, np.nan], [np.nan, np.nan]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "mean of empty slice"
        np.testing.assert_array_equal(nan_mean(x, 0), [2.0, np.nan])
        np.testing.assert_array_equal(nan_std(x, 0), [1.0, np.nan])
        np.testing.assert_array_equal(nan_mean(x, 1), [1.0, 3.0, np.nan])


def test_nan_percentiles_are_numpys_to_the_last_bit() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(200, 4, 9))
    x[rng.random(x.shape) < 0.3] = np.nan
    x[:, 0, 0] = np.nan  # a column without any defined value
    x[1:, 1, 1] = np.nan  # one defined value
    x[:, 2, 2] = 1.5  # constant
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # numpy warns on the all-NaN column
        expected = np.nanpercentile(x, [2.5, 50, 97.5], axis=0)
    for got, want in zip(nan_percentiles(x, (2.5, 50, 97.5)), expected, strict=True):
        np.testing.assert_array_equal(got, want)
    assert np.isnan(nan_percentiles(x, (2.5,))[0][0, 0])
