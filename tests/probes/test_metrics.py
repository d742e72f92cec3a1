"""Metrics against hand-computed values and scikit-learn: AUPRC with ties, confusion counts, the single-class
rule of balanced accuracy, bootstrap intervals."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from vlaprobe.probes.bootstrap import bootstrap_weights
from vlaprobe.probes.metrics import (
    COUNTS,
    atom_metrics,
    average_precision,
    confusion_by_group,
    count_metrics,
    fixed_set,
    layer_means,
    metrics_from_counts,
    resampled_average_precision,
    summarize,
)


def ap(scores: list[float], truth: list[int], weights: list[float] | None = None) -> float:
    """AP of one column; with ``weights``, of one resample counting row i weights[i] times."""
    s = torch.tensor(scores, dtype=torch.float64)[:, None]
    if weights is None:
        return float(average_precision(s, torch.tensor(truth, dtype=torch.bool)[:, None])[0])
    rows = np.arange(len(scores))  # every row its own group
    return float(resampled_average_precision(s, np.array(truth, bool), rows, np.array([weights]))[0, 0])


def test_average_precision_by_hand() -> None:
    # ranks: 1 (+), 2 (-), 3 (+): precisions at the positives 1 and 2/3 -> (1 + 2/3) / 2
    assert ap([0.9, 0.8, 0.7], [1, 0, 1]) == pytest.approx(5 / 6)
    # perfect ranking and the reverse of it
    assert ap([3, 2, 1, 0], [1, 1, 0, 0]) == pytest.approx(1.0)
    assert ap([0, 1, 2, 3], [1, 1, 0, 0]) == pytest.approx((1 / 3 + 2 / 4) / 2)


def test_average_precision_ties_enter_together() -> None:
    # all scores tied: one threshold, precision = prevalence, recall 0 -> 1
    assert ap([0.5, 0.5, 0.5, 0.5], [1, 0, 0, 0]) == pytest.approx(0.25)
    # scores 0.9 (+), then a tie at 0.5 of one + and one -: thresholds give (R, P) = (1/2, 1), (1, 2/3)
    assert ap([0.9, 0.5, 0.5], [1, 1, 0]) == pytest.approx(0.5 * 1 + 0.5 * 2 / 3)
    # the order of tied rows in the input must not matter
    assert ap([0.9, 0.5, 0.5], [1, 0, 1]) == pytest.approx(0.5 * 1 + 0.5 * 2 / 3)


def test_average_precision_undefined_without_positives() -> None:
    assert np.isnan(ap([0.1, 0.2], [0, 0]))


def test_weighted_average_precision_equals_repeated_rows() -> None:
    rng = np.random.default_rng(0)
    scores = rng.integers(0, 4, 12).astype(float)  # many ties
    truth = rng.random(12) < 0.5
    truth[0] = True
    weights = rng.integers(0, 3, 12).astype(float)
    weights[0] = 1
    repeated = np.repeat(np.arange(12), weights.astype(int))
    expected = ap(scores[repeated].tolist(), truth[repeated].astype(int).tolist())
    assert ap(scores.tolist(), truth.astype(int).tolist(), weights.tolist()) == pytest.approx(
        expected, abs=1e-6
    )


def test_confusion_counts_and_metrics() -> None:
    truth = np.array([[1], [1], [0], [0], [0]], bool)
    pred = torch.tensor([[[1], [0], [1], [0], [0]]], dtype=torch.bool)  # one layer
    groups = np.array([0, 0, 1, 1, 1])
    counts = confusion_by_group(pred, truth, groups, 2)
    assert counts.shape == (2, 1, 1, 4)
    assert counts[0, 0, 0].tolist() == [1, 0, 1, 0]  # tp fp fn tn of episode 0
    assert counts[1, 0, 0].tolist() == [0, 1, 0, 2]
    m = metrics_from_counts(counts.sum(0))
    assert m["accuracy"][0, 0] == pytest.approx(3 / 5)
    assert m["balanced_accuracy"][0, 0] == pytest.approx((1 / 2 + 2 / 3) / 2)
    assert m["f1"][0, 0] == pytest.approx(2 * 1 / (2 * 1 + 1 + 1))


def test_undefined_entries_count_in_no_cell() -> None:
    """An atom undefined in a row's task (``defined`` False) is left out of every count of that row: the counts
    equal those of the defined rows alone, whatever the prediction and label there."""
    truth = np.array([[1, 1], [0, 1], [1, 0], [0, 0]], bool)
    pred = torch.tensor([[[1, 0], [1, 1], [0, 0], [0, 1]]], dtype=torch.bool)
    groups = np.array([0, 0, 1, 1])
    defined = np.array([[1, 1], [0, 1], [1, 0], [1, 1]], bool)
    counts = confusion_by_group(pred, truth, groups, 2, defined)
    for atom in range(2):
        keep = defined[:, atom]
        alone = confusion_by_group(pred[:, keep][:, :, [atom]], truth[keep][:, [atom]], groups[keep], 2)
        np.testing.assert_array_equal(counts[:, :, [atom]], alone)
    assert counts.sum((0, 1, 3)).tolist() == [3, 3]  # three defined rows per atom
    np.testing.assert_array_equal(confusion_by_group(pred, truth, groups, 2, np.ones((4, 2), bool)),
                                  confusion_by_group(pred, truth, groups, 2))  # fmt: skip


def test_a_single_class_leaves_balanced_accuracy_and_f1_undefined() -> None:
    assert COUNTS == ("tp", "fp", "fn", "tn")
    m = metrics_from_counts(np.array([[0, 0, 0, 5], [0, 2, 0, 3], [4, 0, 1, 0], [2, 1, 2, 3]], float))
    assert m["accuracy"].tolist() == pytest.approx([1.0, 0.6, 0.8, 5 / 8])
    # no positives (rows 0, 1) or no negatives (row 2): one class, no balanced accuracy
    assert np.isnan(m["balanced_accuracy"][:3]).all()
    assert m["balanced_accuracy"][3] == pytest.approx((2 / 4 + 3 / 4) / 2)
    assert np.isnan(m["f1"][:2]).all() and m["f1"][2] == pytest.approx(8 / 9)


def test_the_issue_toy_case_has_one_answer() -> None:
    # atom 0 both classes (recall 1/2, specificity 1/2); atom 1 only negatives, all predicted right
    truth = np.array([[1, 0], [1, 0], [0, 0], [0, 0]], bool)
    pred = np.array([[[1, 0], [0, 0], [1, 0], [0, 0]]], bool)
    counts = confusion_by_group(pred, truth, np.zeros(4, int), 1)
    point, _ = count_metrics(counts, bootstrap_weights(1, 3, 0))
    value, _ = layer_means(point["balanced_accuracy"], point["balanced_accuracy"][None])
    assert value.tolist() == [0.5]  # atom 1 is left out, not scored as its specificity (1.0 -> 0.75)


def test_metrics_match_scikit_learn_on_random_data() -> None:
    metrics = pytest.importorskip("sklearn.metrics")
    rng = np.random.default_rng(7)
    rows, atoms = 300, 12
    truth = rng.random((rows, atoms)) < rng.uniform(0.05, 0.6, atoms)
    scores = np.where(truth, 1.0, 0.0) * rng.uniform(0, 2, atoms) + rng.normal(0, 1, (rows, atoms))
    scores = np.round(scores, 1)  # ties in the ranking, as AUPRC must handle
    pred = scores > 0.5
    counts = confusion_by_group(pred[None], truth, np.zeros(rows, int), 1)
    m = metrics_from_counts(counts.sum(0))
    ap = average_precision(torch.tensor(scores), torch.tensor(truth)).numpy()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for a in range(atoms):
            y, p = truth[:, a], pred[:, a]
            assert m["accuracy"][0, a] == pytest.approx(metrics.accuracy_score(y, p), abs=1e-12)
            assert m["balanced_accuracy"][0, a] == pytest.approx(
                metrics.balanced_accuracy_score(y, p), abs=1e-12
            )
            assert m["f1"][0, a] == pytest.approx(metrics.f1_score(y, p), abs=1e-12)
            assert ap[a] == pytest.approx(metrics.average_precision_score(y, scores[:, a]), abs=1e-12)
        # where they differ, by rule: one class on the rows
        y, p = np.zeros(10, bool), np.r_[np.ones(2, bool), np.zeros(8, bool)]
        assert metrics.balanced_accuracy_score(y, p) == pytest.approx(0.8)  # the negatives' recall
    one = metrics_from_counts(confusion_by_group(p[None, :, None], y[:, None], np.zeros(10, int), 1).sum(0))
    assert np.isnan(one["balanced_accuracy"][0, 0])


def test_count_metrics_resample_by_weighted_episode_counts() -> None:
    rng = np.random.default_rng(3)
    groups = np.repeat(np.arange(5), 8)
    truth = rng.random((40, 3)) < 0.4
    pred = rng.random((2, 40, 3)) < 0.5
    counts = confusion_by_group(pred, truth, groups, 5)
    w = bootstrap_weights(5, 6, seed=1)
    point, res = count_metrics(counts, w)
    for r in range(6):  # resample r = the rows of its drawn episodes, repeated
        rows = np.concatenate([np.flatnonzero(groups == g).repeat(int(k)) for g, k in enumerate(w[r])])
        direct = metrics_from_counts(
            confusion_by_group(pred[:, rows], truth[rows], np.zeros(len(rows), int), 1)[0]
        )
        for name in point:
            np.testing.assert_allclose(res[name][r], direct[name], rtol=0, atol=1e-12)


def test_bootstrap_intervals_bracket_the_point_and_shrink_with_data() -> None:
    rng = np.random.default_rng(1)

    def interval(num_episodes: int) -> tuple[float, float, float]:
        groups = np.repeat(np.arange(num_episodes), 20)
        truth = rng.random((len(groups), 1)) < 0.5
        noisy = truth ^ (rng.random(truth.shape) < 0.2)
        logits = torch.tensor(np.where(noisy, 1.0, -1.0), dtype=torch.float32)[None]
        w = bootstrap_weights(num_episodes, 400, seed=0)
        point, res = atom_metrics(logits, truth, groups, num_episodes, 0.0, w, auprc_resamples=50)
        s = summarize(point["accuracy"], res["accuracy"], [np.array([0])])
        assert res["auprc"].shape == (50, 1, 1)
        return float(s["atom"]["low"][0, 0]), float(s["atom"]["value"][0, 0]), float(s["atom"]["high"][0, 0])

    lo, v, hi = interval(10)
    assert lo <= v <= hi and 0.6 < v < 0.95
    lo2, _, hi2 = interval(160)
    assert hi2 - lo2 < (hi - lo) / 2


def test_summarize_averages_predicates_over_their_atoms() -> None:
    point = np.array([[0.5, 1.0, np.nan, 0.2]])
    res = np.repeat(point[None], 3, axis=0)
    s = summarize(point, res, [np.array([0, 1]), np.array([2, 3])])
    assert s["predicate"]["value"][0].tolist() == pytest.approx([0.75, 0.2])
    assert s["predicate"]["count"][0].tolist() == [2, 1]
    assert s["layer"]["value"][0] == pytest.approx((0.5 + 1.0 + 0.2) / 3)


def test_f1_is_undefined_without_a_positive_step_even_with_false_positives() -> None:
    m = metrics_from_counts(np.array([[0, 3, 0, 97]], float))  # tp fp fn tn
    assert np.isnan(m["f1"][0]) and m["accuracy"][0] == pytest.approx(0.97)


def test_balanced_accuracy_is_undefined_in_resamples_without_a_positive_episode() -> None:
    # Episode 0 holds the only positives, predicted badly; episodes 1-3 are negatives, predicted right.
    groups = np.repeat(np.arange(4), 10)
    truth = np.zeros((40, 1), bool)
    truth[:10] = True
    pred = np.zeros((40, 1), bool)
    pred[:3] = True  # recall 0.3 on the positives
    logits = torch.tensor(np.where(pred, 1.0, -1.0), dtype=torch.float32)[None]
    w = bootstrap_weights(4, 400, seed=0)
    point, res = atom_metrics(logits, truth, groups, 4, 0.0, w, auprc_resamples=0)
    assert point["balanced_accuracy"][0, 0] == pytest.approx((0.3 + 1.0) / 2)
    without = (w[:, 0] == 0) | (w[:, 0] == 4)  # no positive episode drawn, or only it
    assert (w[:, 0] == 0).any() and np.isnan(res["balanced_accuracy"][without]).all()
    assert not np.isnan(res["balanced_accuracy"][~without]).any()
    assert np.nanmax(res["balanced_accuracy"]) == pytest.approx(0.65)  # never the negatives' recall alone
    s = summarize(point["balanced_accuracy"], res["balanced_accuracy"], [np.array([0])])
    assert s["atom"]["defined"][0, 0] == (~without).sum()
    assert s["layer"]["defined"][0] == (~without).sum() and s["atom"]["high"][0, 0] <= 0.65 + 1e-9


def test_summarize_counts_the_resamples_that_define_each_average() -> None:
    point = np.array([[0.5, 0.7, np.nan]])  # the third atom is undefined at the point: it does not count
    res = np.array([[[0.5, 0.7, np.nan]], [[np.nan, 0.6, np.nan]], [[0.4, 0.6, np.nan]]])
    s = summarize(point, res, [np.array([0, 1]), np.array([2])])
    assert s["atom"]["defined"][0].tolist() == [2, 3, 0]
    assert s["predicate"]["defined"][0].tolist() == [2, 3]
    assert s["layer"]["defined"].tolist() == [2]


def test_interval_of_an_average_stays_centred_when_resamples_lose_rare_atoms() -> None:
    """10 common atoms scored 0.8 and 5 rare ones (positive in one episode of 20) scored 0.5: the layer mean is
    0.7. A third of the resamples miss the rare atoms' episode; averaging only the atoms they define would centre
    the interval near 0.8. Over the fixed set of atoms its centre is the point."""
    rng = np.random.default_rng(0)
    episodes, rows = 20, 10
    groups = np.repeat(np.arange(episodes), rows)
    n = episodes * rows
    truth = np.zeros((n, 15), bool)
    truth[:, :10] = rng.random((n, 10)) < 0.5
    truth[groups == 0, 10:] = True
    pred = truth.copy()
    flip = rng.random((n, 10)) < 0.2
    pred[:, :10] ^= flip  # common atoms: 80% right in each class
    pred[:, 10:] = False  # rare atoms: never predicted, balanced accuracy 0.5
    logits = torch.where(torch.as_tensor(pred), 1.0, -1.0)[None].float()
    weights = bootstrap_weights(episodes, 2000, seed=0)
    point, res = atom_metrics(logits, truth, groups, episodes, 0.0, weights, 0)
    layer = summarize(point["balanced_accuracy"], res["balanced_accuracy"], [np.arange(15)])["layer"]
    value, low, high = float(layer["value"][0]), float(layer["low"][0]), float(layer["high"][0])
    assert value == pytest.approx((10 * 0.8 + 5 * 0.5) / 15, abs=0.02)
    fixed = np.nanmean(fixed_set(point["balanced_accuracy"], res["balanced_accuracy"]), axis=2)[:, 0]
    changing = np.nanmean(res["balanced_accuracy"], axis=2)[:, 0]
    assert abs(fixed.mean() - value) < 0.01 and abs(np.median(fixed) - value) < 0.01 and low < value < high
    assert changing.mean() - value > 0.02  # the bias this removes
    assert layer["defined"][0] < 2000 * 0.8  # resamples missing the rare episode are counted


def test_resampled_average_precision_draws_whole_groups_at_every_column() -> None:
    rng = np.random.default_rng(1)
    rows, groups = 40, 5
    group = rng.integers(0, groups, rows)
    truth = (rng.random(rows) < 0.4) & (group != 0)  # group 0 has no positive row
    scores = torch.as_tensor(rng.integers(0, 6, (rows, 3)).astype(float))  # ties in every column
    draws = bootstrap_weights(groups, 7, seed=0)
    draws[0] = [5, 0, 0, 0, 0]  # group 0 alone: no positive drawn, undefined
    got = resampled_average_precision(scores, truth, group, draws, budget=rows * groups)  # a column per chunk
    assert np.isnan(got[0]).all()
    for r in range(1, len(draws)):
        repeated = np.repeat(np.arange(rows), draws[r][group].astype(int))
        expected = average_precision(
            scores[repeated], torch.as_tensor(truth[repeated])[:, None].expand(-1, 3)
        )
        np.testing.assert_allclose(got[r], expected.numpy(), rtol=1e-6)
