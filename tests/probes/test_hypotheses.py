"""H1/H2 on synthetic curves with a known answer; curves by hand; and on a store and probes made by the real
writers and ``vlaprobe train``, curves and intervals equal to ``evaluation.json``'s."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from vlaprobe.collection.store import EpisodeInfo
from vlaprobe.collection.writer import StoreWriter
from vlaprobe.configs.hypotheses import HypothesesConfig
from vlaprobe.configs.train import ProbeConfig, SplitConfig, TrainConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes import synthetic_data
from vlaprobe.probes.bootstrap import bootstrap_weights, percentile_interval
from vlaprobe.probes.hypotheses import LayerCurves, answer_hypotheses, curves_from_counts, layer_statistics
from vlaprobe.probes.hypotheses_run import hypotheses, run_curves
from vlaprobe.probes.metrics import confusion_by_group
from vlaprobe.probes.results import DECIMALS
from vlaprobe.probes.split import make_folds
from vlaprobe.probes.train import train_probes

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


def test_curves_by_hand_leave_single_class_atoms_out() -> None:
    labels = np.array([[1, 0], [0, 0], [1, 0], [0, 1]], bool)  # rows x atoms
    preds = np.array([[[1, 0], [1, 0], [0, 0], [0, 1]]], bool)  # one layer
    counts = confusion_by_group(preds, labels, np.array([0, 0, 1, 1]), 2)
    np.testing.assert_array_equal(counts[0, 0], [[1, 1, 0, 0], [0, 0, 0, 2]])  # tp fp fn tn
    np.testing.assert_array_equal(counts[1, 0], [[0, 0, 1, 1], [1, 0, 0, 1]])
    # resample 0 = both episodes: atom 0 recall 1/2, specificity 1/2 -> 0.5; atom 1: 1 and 1 -> 1.0; mean 0.75
    # resample 1 = episode 0 twice: atom 1 has no positive -> undefined, enters with its point value 1.0;
    #   atom 0: recall 1, specificity 0 -> 0.5; mean 0.75
    # resample 2 = episode 1 twice: atom 0 recall 0, specificity 1 -> 0.5, atom 1 1.0
    weights = np.array([[1.0, 1.0], [2.0, 0.0], [0.0, 2.0]])
    c = curves_from_counts({"object": counts, "action": counts}, [0], weights)
    np.testing.assert_allclose(c.point["object"], [0.75])
    np.testing.assert_allclose(c.resamples["object"][:, 0], [0.75, 0.75, 0.75])
    only_negatives = counts.copy()
    only_negatives[:, :, 1] = [[0, 0, 0, 2]]  # atom 1 never true: left out, not scored by its specificity
    c = curves_from_counts({"object": only_negatives, "action": counts}, [0], weights)
    np.testing.assert_allclose(c.point["object"], [0.5])
    assert c.episodes == 2


def test_resamples_are_drawn_jointly_for_both_heads() -> None:
    rng = np.random.default_rng(1)
    labels = rng.random((60, 5)) < 0.4
    preds = labels[None] ^ (rng.random((4, 60, 5)) < np.linspace(0.4, 0.05, 4)[:, None, None])
    counts = confusion_by_group(preds, labels, np.repeat(np.arange(6), 10), 6)
    c = curves_from_counts({"object": counts, "action": counts}, range(4), bootstrap_weights(6, 50, seed=3))
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


# ----- on a store written by the real writers, probes trained by `vlaprobe train` ----------------------------
def _write_store(path: Path, model_id: str = "synthetic", steps: int = 24) -> None:
    """Synthetic episodes with planted structure; object atom 0 is true on two whole training episodes and
    false on every test episode: one class on the scored rows."""
    data = synthetic_data(4, 5, steps, num_layers=4, hidden_size=16, num_object=10, num_action=4, signal=6.0)
    (fold,) = make_folds(data.episode_tasks, SplitConfig(), seed=0)  # the split `vlaprobe train` makes
    atom0 = np.isin(data.episode, fold.train[:2])
    data.labels["object"][:, 0] = atom0
    meta = {
        "atom_names": data.atom_names,
        "model_id": model_id,
        "model": {"model_id": model_id},
        "num_hidden_states": 4,
        "hidden_size": 16,
        "pooling": "last_prompt",
        "driver": "expert",
        "suite": "libero_spatial",
        "env": {},
        "seed": 0,
        "instructions": {str(t): f"task {t}" for t in range(4)},
    }
    with StoreWriter.open(path, meta) as writer:
        for e, key in enumerate(data.episode_keys):
            rows = data.episode == e
            info = EpisodeInfo(
                key, int(data.episode_tasks[e]), e, 0, True, int(rows.sum()), seed=e, driver="expert"
            )
            arrays = {
                "hidden": data.hidden[:, rows].numpy(),
                "object_atoms": data.labels["object"][rows],
                "action_atoms": data.labels["action"][rows],
            }
            writer.write_episode(info, arrays)


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("hyp")
    _write_store(root / "activations")
    cfg = TrainConfig(
        store=root / "activations",
        out=root / "probes",
        bootstrap=300,
        auprc_bootstrap=400,  # more than `bootstrap`: train scores counts on the first 300 of 400 draws
        shuffled_permutations=1,
        probe=ProbeConfig(c_grid=(0.1, 1.0)),
    )
    return train_probes(cfg)


def test_curves_and_intervals_equal_the_evaluation(trained: Path) -> None:
    ev = json.loads((trained / "evaluation.json").read_text())
    curves = run_curves(trained, None)
    assert curves.episodes == ev["split"]["test"]["episodes"] and curves.resamples["object"].shape[0] == 300
    obj = ev["heads"]["object"]
    assert (
        obj["probe"]["balanced_accuracy"]["atom"]["value"][0][obj["atoms"].index("behind(obj_0,obj_1)")]
        is None
    )
    for head in ("object", "action"):
        layer = ev["heads"][head]["probe"]["balanced_accuracy"]["layer"]
        low, high = percentile_interval(curves.resamples[head])
        for ours, theirs in ((curves.point[head], "value"), (low, "low"), (high, "high")):
            np.testing.assert_allclose(
                np.round(ours, DECIMALS), np.array(layer[theirs], float), rtol=0, atol=1e-9
            )
    result = hypotheses(HypothesesConfig(probes=trained))
    for head, h in result.heads.items():
        best = ev["heads"][head]["probe"]["balanced_accuracy"]["layer"]
        i = curves.layers.index(h.best)
        assert round(h.best_value, DECIMALS) == pytest.approx(best["value"][i], abs=1e-9)
        assert [round(x, DECIMALS) for x in h.best_value_interval] == pytest.approx(
            [best["low"][i], best["high"][i]], abs=1e-9
        )
    with pytest.raises(VlaprobeError, match="too few"):
        run_curves(trained, None, resamples=5)
    other = run_curves(trained, None, seed=ev["seeds"]["bootstrap"] + 1)  # other resamples: other intervals
    np.testing.assert_array_equal(other.point["object"], curves.point["object"])
    assert not np.allclose(
        percentile_interval(other.resamples["object"])[0], percentile_interval(curves.resamples["object"])[0]
    )


def test_a_negative_seed_is_one_line(trained: Path) -> None:  # the fuzzer's find: numpy's ValueError
    with pytest.raises(VlaprobeError, match="--seed must be at least 0"):
        hypotheses(HypothesesConfig(probes=trained, seed=-1))


@pytest.mark.parametrize(
    ("model_id", "steps", "words"),
    [("other", 24, "observed by model 'other'"), ("synthetic", 20, "another collection")],
)
def test_a_store_the_probes_were_not_trained_on_is_refused(
    trained: Path, tmp_path: Path, model_id: str, steps: int, words: str
) -> None:
    _write_store(tmp_path / "other", model_id=model_id, steps=steps)
    with pytest.raises(VlaprobeError, match=words):
        hypotheses(HypothesesConfig(probes=trained, store=tmp_path / "other"))
    assert not (trained / "hypotheses.json").exists() or run_curves(
        trained, None
    )  # the folder's own still runs


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("{}", "is not a vlaprobe evaluation"),
        ("", "cannot read"),
        ('{"format": "vlaprobe-evaluation", "format_version": 4}', "is damaged"),
    ],
)
def test_an_empty_or_malformed_evaluation_is_one_line(
    trained: Path, tmp_path: Path, text: str, words: str
) -> None:
    folder = tmp_path / "probes"
    shutil.copytree(trained, folder)
    (folder / "evaluation.json").write_text(text)
    with pytest.raises(VlaprobeError, match=words):
        hypotheses(HypothesesConfig(probes=folder))
