"""The whole experiment on synthetic data: files, split, filter, controls, best layer, k-fold, errors."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from vlaprobe.configs import config_from_dict
from vlaprobe.configs.train import ProbeConfig, SplitConfig, TrainConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes import ProbeSet, synthetic_data, train_on_data
from vlaprobe.probes.data import ProbeData
from vlaprobe.probes.probemeta import read_probes_meta

FAST = dict(bootstrap=200, auprc_bootstrap=20)


def small_data(seed: int = 0) -> ProbeData:
    return synthetic_data(
        num_tasks=3,
        episodes_per_task=5,
        steps_per_episode=30,
        num_layers=4,
        hidden_size=32,
        num_object=18,
        num_action=4,
        signal=8.0,
        seed=seed,
    )


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> dict:
    data = small_data()
    noise = torch.randn(data.hidden.shape, generator=torch.Generator().manual_seed(5)).half()
    observer = dataclasses.replace(data, hidden=noise, model_id="random-init")
    cfg = TrainConfig(**FAST)
    out = train_on_data(data, cfg, tmp_path_factory.mktemp("probes"), observer=observer)
    return {
        "data": data,
        "cfg": cfg,
        "out": out,
        "ev": json.loads((out / "evaluation.json").read_text()),
        "meta": read_probes_meta(out),
    }


def test_output_folder_is_complete(run: dict) -> None:
    out = run["out"]
    assert sorted(p.name for p in out.iterdir()) == [
        "config.json",
        "evaluation.json",
        "probes.json",
        "probes.safetensors",
    ]
    cfg = config_from_dict(TrainConfig, json.loads((out / "config.json").read_text()))
    assert cfg == run["cfg"]  # the recorded config reproduces the run
    meta = run["meta"]
    assert meta.model_id == "synthetic" and meta.config["probe"]["tol"] == run["cfg"].probe.tol
    assert set(meta.seeds) == {"split", "probe", "shuffle", "bootstrap"}


def test_split_is_by_episode_and_stratified(run: dict) -> None:
    data, split = run["data"], run["ev"]["split"]
    test_keys = split["test_episodes"]
    assert len(test_keys) == 3  # one of five per task
    assert sorted(int(k[1:3]) for k in test_keys) == [0, 1, 2]
    assert split["train"]["episodes"] + split["test"]["episodes"] == len(data.episode_keys)
    assert split["test"]["steps"] == 3 * 30


def test_filter_drops_exactly_the_constant_atoms(run: dict) -> None:
    data, ev = run["data"], run["ev"]
    for head in ("object", "action"):
        y = data.labels[head]
        test = np.isin(data.episode, [data.episode_keys.index(k) for k in ev["split"]["test_episodes"]])
        freq = y[~test].mean(0)
        expected = sorted(a for a, f in zip(data.atom_names[head], freq, strict=True) if f < 0.01 or f > 0.99)
        assert sorted(d["atom"] for d in ev["heads"][head]["dropped"]) == expected
        assert len(ev["heads"][head]["atoms"]) + len(expected) == len(data.atom_names[head])
    # a predicate whose atoms were all dropped is left out and listed
    obj = ev["heads"]["object"]
    for p in obj["skipped_predicates"]:
        assert p not in obj["predicates"]


def test_metrics_have_layer_by_atom_shapes_and_intervals(run: dict) -> None:
    ev = run["ev"]
    layers = len(ev["layers"])
    for head, h in ev["heads"].items():
        atoms, preds = len(h["atoms"]), len(h["predicates"])
        for metric in ("accuracy", "balanced_accuracy", "f1", "auprc"):
            s = h["probe"][metric]
            assert np.array(s["atom"]["value"], float).shape == (layers, atoms)
            assert np.array(s["predicate"]["value"], float).shape == (layers, preds)
            v, lo, hi = (np.array(s["layer"][k], float) for k in ("value", "low", "high"))
            ok = ~np.isnan(lo)
            # a percentile interval need not hold its point estimate exactly: at the top of its range the
            # resampled AUPRC (from per-episode counts) can fall a few 1e-8 below the point (files keep 10 decimals)
            tol = 1e-6
            assert ok.any() and np.all(lo[ok] <= v[ok] + tol) and np.all(v[ok] <= hi[ok] + tol), (
                head,
                metric,
            )
        assert np.array(h["baseline"]["accuracy"]["atom"]["value"], float).shape == (1, atoms)


def test_probes_beat_controls_and_best_layer_is_recorded(run: dict) -> None:
    ev, meta = run["ev"], run["meta"]
    obj = ev["heads"]["object"]
    acc = np.array(obj["probe"]["accuracy"]["layer"]["value"])
    control = np.array(obj["control"]["accuracy"]["layer"]["value"])
    observer = np.array(obj["observer"]["accuracy"]["layer"]["value"])
    baseline = obj["baseline"]["accuracy"]["layer"]["value"][0]
    assert acc.max() > baseline + 0.15
    assert np.all(np.abs(control - baseline) < 0.08)
    assert np.all(np.abs(observer - baseline) < 0.08)  # random hidden states carry no label
    selectivity = np.array(obj["selectivity"]["accuracy"]["layer"]["value"])
    np.testing.assert_allclose(selectivity, acc - control, atol=1e-4)
    best = obj["best"]
    assert best["metric"] == "balanced_accuracy"
    bal = np.array(obj["probe"]["balanced_accuracy"]["layer"]["value"])
    assert best["layer"] == ev["layers"][int(np.argmax(bal))]
    head = meta.heads["object"]
    assert head.best_layer == best["layer"] and head.best_metric == best["metric"]
    assert head.tied_layers == sorted({*best["tied"], best["layer"]}) and head.default_layer == min(
        head.tied_layers
    )
    assert ev["controls"]["observer"]["model_id"] == "random-init"


def test_saved_probes_predict_like_the_evaluation(run: dict) -> None:
    data, out, ev = run["data"], run["out"], run["ev"]
    probes = ProbeSet.load(out, model_id="synthetic", pooling="last_prompt")
    head = "object"
    layer = probes.best_layer(head)
    keys = ev["split"]["test_episodes"]
    rows = np.flatnonzero(np.isin(data.episode, [data.episode_keys.index(k) for k in keys]))
    names = probes.atoms(head)
    cols = [data.atom_names[head].index(a) for a in names]
    truth = data.labels[head][rows][:, cols]
    pred = np.array([[probes.predict(data.hidden[:, r], layer, head)[a] for a in names] for r in rows])
    accuracy = (pred == truth).mean()
    i = ev["layers"].index(layer)
    assert accuracy == pytest.approx(
        np.nanmean(np.array(ev["heads"][head]["probe"]["accuracy"]["atom"]["value"][i], float)), abs=1e-4
    )  # JSON keeps 5 decimals


def test_kfold_tests_every_episode_once_and_refits_on_all(tmp_path: Path) -> None:
    data = small_data(seed=1)
    cfg = TrainConfig(split=SplitConfig(folds=3), shuffled_control=False, **FAST)
    out = train_on_data(data, cfg, tmp_path)
    ev = json.loads((out / "evaluation.json").read_text())
    assert sorted(ev["split"]["test_episodes"]) == sorted(data.episode_keys)
    assert ev["heads"]["object"]["control"] is None
    assert read_probes_meta(out).trained_on.split.startswith("all episodes")


def test_bad_requests_are_one_line_errors(tmp_path: Path) -> None:
    data = small_data()
    with pytest.raises(VlaprobeError, match="no label head"):
        train_on_data(data, TrainConfig(heads=("colour",), **FAST), tmp_path)
    constant = dataclasses.replace(data, labels={h: np.zeros_like(y) for h, y in data.labels.items()})
    with pytest.raises(VlaprobeError, match="every atom") as err:
        train_on_data(constant, TrainConfig(**FAST), tmp_path)
    assert "\n" not in str(err.value)
    assert not list(tmp_path.iterdir())  # nothing half-written


def test_a_head_without_varying_atoms_is_skipped_and_recorded(tmp_path: Path) -> None:
    data = small_data()
    labels = {**data.labels, "action": np.zeros_like(data.labels["action"])}
    out = train_on_data(dataclasses.replace(data, labels=labels), TrainConfig(**FAST), tmp_path)
    ev = json.loads((out / "evaluation.json").read_text())
    assert list(ev["heads"]) == ["object"]
    assert len(ev["skipped_heads"]["action"]["dropped"]) == 4
    assert ProbeSet.load(out).heads == ["object"]


def test_shuffled_control_is_the_mean_of_several_permutations(run: dict, tmp_path: Path) -> None:
    ev = run["ev"]
    obj = ev["heads"]["object"]
    assert ev["controls"]["shuffled_permutations"] == 5
    spread = np.array(obj["control_spread"]["accuracy"]["layer"], float)
    assert spread.shape == (len(ev["layers"]),) and np.all(spread > 0)  # the permutations differ
    # One permutation is a different (noisier) control than the mean of five.
    one = train_on_data(run["data"], TrainConfig(shuffled_permutations=1, **FAST), tmp_path)
    single = json.loads((one / "evaluation.json").read_text())["heads"]["object"]
    assert not np.allclose(
        np.array(single["control"]["accuracy"]["layer"]["value"], float),
        np.array(obj["control"]["accuracy"]["layer"]["value"], float),
    )
    assert np.all(np.array(single["control_spread"]["accuracy"]["layer"], float) == 0)


def test_realized_test_fraction_is_recorded_next_to_the_requested_one(run: dict) -> None:
    split = run["ev"]["split"]
    assert split["test_fraction"] == 0.2 and split["realized_test_fraction"] == pytest.approx(3 / 15)
    data = small_data()
    three = dataclasses.replace(data)  # 5 episodes per task: round(0.33 * 5) = 2 held out per task
    ev = train_on_data(
        three, TrainConfig(split=SplitConfig(test_fraction=0.33), **FAST), Path(run["out"]).parent / "f"
    )
    split = json.loads((ev / "evaluation.json").read_text())["split"]
    assert split["test_fraction"] == 0.33 and split["realized_test_fraction"] == pytest.approx(6 / 15)


def test_evaluation_records_how_every_probe_was_fit(run: dict) -> None:
    ev = run["ev"]
    layers = len(ev["layers"])
    for h in ev["heads"].values():
        fit = h["fit"]
        shape = (layers, len(h["atoms"]))
        for key in ("iterations", "loss", "grad_norm"):
            assert np.array(fit[key], float).shape == shape, key
        assert fit["at_cap"] == 0 and fit["probes"] == layers * len(h["atoms"])
        assert np.nanmax(np.array(fit["grad_norm"], float)) <= fit["tol"]
        assert fit["standardized"] and fit["cv_folds"] == 3
        assert np.array(fit["cv_loss"], float).shape == (layers, len(fit["c_grid"]))
        assert set(fit["c"]) <= set(fit["c_grid"])  # one C per layer, chosen from the grid
        assert np.array(fit["cv_score"], float).shape == (layers, len(fit["c_grid"]))
        assert len(fit["c_at_edge"]) == layers and "balanced accuracy" in fit["c_rule"]


def test_probes_stopped_at_the_cap_are_counted_and_warned_about(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    cfg = TrainConfig(shuffled_control=False, probe=ProbeConfig(max_iter=2), **FAST)
    with caplog.at_level("WARNING", logger="vlaprobe.probes"):
        out = train_on_data(small_data(), cfg, tmp_path)
    fit = json.loads((out / "evaluation.json").read_text())["heads"]["object"]["fit"]
    assert fit["at_cap"] == fit["probes"] > 0 and np.max(fit["iterations"]) == 2
    assert (
        "stopped at --probe.max-iter 2 above the tolerance" in caplog.text
        and "raise --probe.max-iter" in caplog.text
    )


@pytest.mark.parametrize("heads", [("object", "action"), ("action",)])
@pytest.mark.parametrize("standardize", [True, False])
def test_saved_and_loaded_probes_equal_the_trained_ones(
    tmp_path: Path, heads: tuple[str, ...], standardize: bool
) -> None:
    data = small_data()
    cfg = TrainConfig(
        heads=heads, shuffled_control=False, bootstrap=20, auprc_bootstrap=0,
        probe=ProbeConfig(standardize=standardize, c_grid=(0.1,)),
    )  # fmt: skip
    out = train_on_data(data, cfg, tmp_path / "p")
    probes = ProbeSet.load(out)
    assert probes.heads == list(heads) and probes.meta.standardized is standardize
    assert all((f"{h}.mean" in probes.tensors) is standardize for h in heads)
    ev = json.loads((out / "evaluation.json").read_text())
    rows = np.flatnonzero(
        np.isin(data.episode, [data.episode_keys.index(k) for k in ev["split"]["test_episodes"]])
    )
    for h in heads:
        names = probes.atoms(h)
        cols = [data.atom_names[h].index(a) for a in names]
        layer = probes.best_layer(h)
        i = ev["layers"].index(layer)
        live = np.array([[probes.predict(data.hidden[:, r], layer, h)[a] for a in names] for r in rows])
        accuracy = (live == data.labels[h][rows][:, cols]).mean()
        offline = np.nanmean(np.array(ev["heads"][h]["probe"]["accuracy"]["atom"]["value"][i], float))
        assert accuracy == pytest.approx(offline, abs=1e-4)  # readout applies the saved standardisation
