"""H1/H2 on synthetic curves with a known answer; layer statistics, counts and balanced accuracy by hand."""

from __future__ import annotations

import numpy as np

from vlaprobe.probes.hypotheses import (
    LayerCurves,
    answer_hypotheses,
    balanced_accuracy_curve,
    curves_from_counts,
    episode_counts,
    layer_statistics,
)

LAYERS = tuple(range(33))


def sigmoid_curve(rise_at: float, top: float = 0.9, peak: int | None = None) -> np.ndarray:
    x = np.arange(33, dtype=float)
    c = 0.5 + (top - 0.5) / (1 + np.exp(-(x - rise_at) * 1.5))
    if peak is not None:
        c = c - 0.002 * np.abs(x - peak)  # a gentle maximum at `peak`
    return c


def curves(obj: np.ndarray, act: np.ndarray, noise: float = 0.01, b: int = 300) -> LayerCurves:
    rng = np.random.default_rng(0)
    shift = rng.normal(0, noise, (b, 1))  # episode resamples move both heads together, plus own noise
    return LayerCurves(
        LAYERS,
        {"object": obj, "action": act},
        {
            "object": obj + shift + rng.normal(0, noise / 3, (b, 33)),
            "action": act + shift + rng.normal(0, noise / 3, (b, 33)),
        },
    )


def test_layer_statistics_of_a_hand_made_curve() -> None:
    curve = np.array([0.2, 0.5, 0.6, 0.6, 0.9, 0.91, 0.9])
    # the rise 0.2 -> 0.5 out of hidden state 0 is left out; the steepest is into layer 4
    assert layer_statistics(curve, range(7), tolerance=0.02) == {"best": 5, "earliest": 4, "steepest": 4}
    assert layer_statistics(curve, range(7), tolerance=0.0) == {"best": 5, "earliest": 5, "steepest": 4}
    assert layer_statistics(curve[1:], range(1, 7), 0.02)["steepest"] == 4  # no state 0: every rise counts


def test_object_early_action_late_supports_both_hypotheses() -> None:
    result = answer_hypotheses(curves(sigmoid_curve(6, peak=12), sigmoid_curve(20, peak=28)))
    obj, act = result.heads["object"], result.heads["action"]
    assert obj.best == 12 and act.best == 28 and obj.steepest in (6, 7) and act.steepest in (20, 21)
    assert obj.earliest < act.earliest
    assert [v.verdict for v in result.verdicts] == ["support", "support"]
    d = result.differences["best"]
    assert d.value == -16 and d.low <= -16 <= d.high and d.high < 0
    assert "H1" in result.verdicts[0].sentence and "95% interval" in result.verdicts[0].sentence


def test_reversed_curves_contradict_and_equal_ones_cannot_tell() -> None:
    reversed_ = answer_hypotheses(curves(sigmoid_curve(20, peak=28), sigmoid_curve(6, peak=12)))
    assert [v.verdict for v in reversed_.verdicts] == ["contradict", "contradict"]
    same = sigmoid_curve(10, peak=20)
    flat = answer_hypotheses(curves(same, same + 0.0, noise=0.03))
    assert [v.verdict for v in flat.verdicts] == ["cannot tell", "cannot tell"]
    assert all(d.low <= 0 <= d.high for d in flat.differences.values())


def test_counts_and_balanced_accuracy_by_hand() -> None:
    labels = np.array([[1, 0], [0, 0], [1, 0], [0, 1]], bool)  # rows x atoms
    preds = np.array([[[1, 0], [1, 0], [0, 0], [0, 1]]], bool)  # one layer
    counts = episode_counts(labels, preds, np.array([0, 0, 1, 1]), 2)
    assert counts.shape == (2, 1, 2, 4)
    np.testing.assert_array_equal(counts[0, 0], [[1, 0, 1, 0], [0, 0, 0, 2]])  # tp fn fp tn
    np.testing.assert_array_equal(counts[1, 0], [[0, 1, 0, 1], [1, 0, 0, 1]])
    total = counts.sum(axis=0)
    # atom 0: recall 1/2, specificity 1/2 -> 0.5; atom 1: 1 and 1 -> 1.0; mean 0.75
    np.testing.assert_allclose(balanced_accuracy_curve(total), [0.75])
    # episode 0 alone: atom 1 has no positive -> undefined and left out; atom 0: recall 1, spec 0 -> 0.5
    np.testing.assert_allclose(balanced_accuracy_curve(counts[0]), [0.5])


def test_resamples_are_drawn_jointly_for_both_heads() -> None:
    rng = np.random.default_rng(1)
    labels = rng.random((60, 5)) < 0.4
    preds = labels[None] ^ (rng.random((4, 60, 5)) < np.linspace(0.4, 0.05, 4)[:, None, None])
    counts = episode_counts(labels, preds, np.repeat(np.arange(6), 10), 6)
    c = curves_from_counts({"object": counts, "action": counts}, range(4), resamples=50, seed=3)
    np.testing.assert_array_equal(c.resamples["object"], c.resamples["action"])  # same episodes drawn
    result = answer_hypotheses(c)
    assert all(d.value == d.low == d.high == 0 for d in result.differences.values())
    assert c.point["object"][3] > c.point["object"][0]


def test_too_few_test_episodes_cannot_tell() -> None:
    c = curves(sigmoid_curve(6, peak=12), sigmoid_curve(20, peak=28))
    few = answer_hypotheses(LayerCurves(c.layers, c.point, c.resamples, episodes=2))
    assert [v.verdict for v in few.verdicts] == ["cannot tell", "cannot tell"]
    assert "Only 2 test episodes" in few.verdicts[0].sentence and few.episodes == 2
    enough = answer_hypotheses(LayerCurves(c.layers, c.point, c.resamples, episodes=10))
    assert [v.verdict for v in enough.verdicts] == ["support", "support"]
