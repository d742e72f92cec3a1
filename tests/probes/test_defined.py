"""Undefined entries (union stores): weight 0 in fit_logistic is fitting on the defined rows only."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from vlaprobe.configs.train import ProbeConfig, TrainConfig
from vlaprobe.probes import train_on_data
from vlaprobe.probes.bootstrap import bootstrap_weights
from vlaprobe.probes.data import ProbeData, synthetic_data
from vlaprobe.probes.lbfgs import fit_logistic, l2_of_c
from vlaprobe.probes.matched import pair_counts
from vlaprobe.probes.metrics import METRICS, atom_metrics
from vlaprobe.probes.regularization import ColumnGroups, _held_out, choose_c
from vlaprobe.probes.results import read_evaluation
from vlaprobe.probes.split import filter_labels
from vlaprobe.probes.trainer import fit_probes


def _problem() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(120, 5)).astype(np.float32)
    y = np.stack([x[:, 0] + 0.5 * rng.normal(size=120) > 0, x[:, 1] - x[:, 2] > 0.3], 1).astype(np.float32)
    defined = np.ones_like(y, dtype=bool)
    defined[:40, 0] = False  # column 0 undefined in the first 40 rows (an object absent from those episodes)
    y[~defined] = 1.0  # garbage where undefined: must not matter
    return x, y, defined


def test_weight_zero_equals_fitting_on_the_defined_rows() -> None:
    x, y, defined = _problem()
    c = 0.7
    n = defined.sum(0)
    w, b, _ = fit_logistic(
        torch.from_numpy(x)[None],
        torch.from_numpy(y),
        torch.from_numpy(l2_of_c(np.full((1, 2), c), n)).float(),
        weight=torch.from_numpy(defined.astype(np.float32)),
        tol=1e-9,
        max_iter=5000,
    )
    rows = defined[:, 0]
    w0, b0, _ = fit_logistic(
        torch.from_numpy(x[rows])[None],
        torch.from_numpy(y[rows, :1]),
        torch.from_numpy(l2_of_c(np.full((1, 1), c), rows.sum())).float(),
        tol=1e-9,
        max_iter=5000,
    )
    np.testing.assert_allclose(w[0, :, 0].numpy(), w0[0, :, 0].numpy(), atol=1e-4)
    assert float(b[0, 0]) == pytest.approx(float(b0[0, 0]), abs=1e-4)
    linear_model = pytest.importorskip("sklearn.linear_model")
    model = linear_model.LogisticRegression(C=c, tol=1e-10, max_iter=10000)
    model.fit(x, y[:, 0], sample_weight=defined[:, 0].astype(float))
    np.testing.assert_allclose(w[0, :, 0].numpy(), model.coef_[0], atol=1e-3)
    assert float(b[0, 0]) == pytest.approx(float(model.intercept_[0]), abs=1e-3)


def test_probe_data_without_a_mask_is_all_defined() -> None:
    data = synthetic_data(num_tasks=2, episodes_per_task=1, steps_per_episode=3)
    assert (
        data.defined_mask("object").all() and data.defined_mask("object").shape == data.labels["object"].shape
    )
    with pytest.raises(ValueError, match="defined"):
        type(data)(**{**data.__dict__, "defined": {"object": np.ones((1, 1), bool)}})


# -- known answers: with the mask every figure equals the figure of the defined rows alone ---------------------
G = 6  # test episodes


def _scored(seed: int = 0) -> tuple[torch.Tensor, np.ndarray, np.ndarray, np.ndarray]:
    """(logits (2, 60, 3), truth, groups, defined): atom 0 undefined in episodes 0-1, atom 2 in episode 5; the
    undefined entries are stored false (as a union store writes them) and scored confidently true, so that
    counting them changes every figure."""
    rng = np.random.default_rng(seed)
    groups = np.repeat(np.arange(G), 10)
    truth = rng.random((60, 3)) < 0.4
    defined = np.ones_like(truth)
    defined[groups < 2, 0] = False
    defined[groups == 5, 2] = False
    truth[~defined] = False
    logits = torch.from_numpy(rng.normal(size=(2, 60, 3)) + 1.5 * (truth - 0.5)).float()
    logits[:, torch.from_numpy(~defined)] = 4.0
    return logits, truth, groups, defined


def test_masked_metrics_equal_those_of_the_defined_rows_alone() -> None:
    logits, truth, groups, defined = _scored()
    weights = bootstrap_weights(G, 50, 0)
    point, res = atom_metrics(logits, truth, groups, G, 0.0, weights, 50, defined)
    plain, _ = atom_metrics(logits, truth, groups, G, 0.0, weights, 50)
    for a in range(3):
        keep = defined[:, a]
        alone, alone_res = atom_metrics(
            logits[:, keep][:, :, [a]], truth[keep][:, [a]], groups[keep], G, 0.0, weights, 50
        )
        for m in METRICS:
            np.testing.assert_allclose(point[m][:, [a]], alone[m], err_msg=m)
            np.testing.assert_allclose(res[m][:, :, [a]], alone_res[m], err_msg=m)
    for m in METRICS:  # the undefined entries would have counted: the test can fail
        assert not np.allclose(point[m][:, 0], plain[m][:, 0]), m
    np.testing.assert_allclose(point["auprc"][:, 1], plain["auprc"][:, 1])  # atom 1: defined everywhere


def test_masked_matched_pairs_equal_those_of_the_defined_rows_alone() -> None:
    logits, truth, groups, defined = _scored(1)
    cells = np.tile(np.repeat(np.arange(2), 5), G)  # two cells per episode
    correct, pairs = pair_counts(logits, truth, cells, groups, G, defined=defined)
    _, plain = pair_counts(logits, truth, cells, groups, G)
    for a in range(3):
        keep = defined[:, a]
        c, p = pair_counts(logits[:, keep][:, :, [a]], truth[keep][:, [a]], cells[keep], groups[keep], G)
        np.testing.assert_allclose(correct[:, [a]], c)
        np.testing.assert_allclose(pairs[[a]], p)
    assert pairs[0].sum() < plain[0].sum()  # the undefined false entries made pairs before


def test_masked_held_out_scores_equal_those_of_the_defined_rows_alone() -> None:
    rng = np.random.default_rng(2)
    _, truth, _, defined = _scored(2)
    x = torch.from_numpy(rng.normal(size=(2, 60, 4))).float()
    w, b = torch.from_numpy(rng.normal(size=(2, 4, 3))).float(), torch.zeros(2, 3)
    rows = np.arange(60)
    loss, balanced = _held_out(x, rows, truth, w, b, 0.0, defined=defined)
    plain_loss, _ = _held_out(x, rows, truth, w, b, 0.0)
    for a in range(3):
        keep = np.flatnonzero(defined[:, a])
        l1, b1 = _held_out(x, keep, truth[keep][:, [a]], w[:, :, [a]], b[:, [a]], 0.0)
        np.testing.assert_allclose(loss[:, [a]], l1, rtol=1e-6)
        np.testing.assert_allclose(balanced[:, [a]], b1)
    assert not np.allclose(loss[:, 0], plain_loss[:, 0])


def test_masked_fit_and_c_search_equal_fitting_on_the_defined_rows_alone() -> None:
    """Column 0 is undefined on the first third of every episode (so the folds keep every episode); each
    column is its own C group: the C search and the fit of column 0 are those of its defined rows."""
    data = synthetic_data(num_tasks=2, episodes_per_task=4, steps_per_episode=30, num_layers=2, hidden_size=8,
                          num_object=2, num_action=0, constant_fraction=0.0, outlier_dims=0, seed=3, dtype=torch.float32)  # fmt: skip
    targets = data.labels["object"].copy()
    defined = np.ones_like(targets)
    defined[np.arange(len(targets)) % 30 < 10, 0] = False
    targets[~defined] = False
    groups = ColumnGroups(data.episode, data.episode_tasks, np.arange(2), np.ones(2, bool))
    cfg = ProbeConfig(standardize=False, c_grid=(0.01, 0.1, 1.0), tol=1e-7, max_iter=3000, cv_folds=2)
    rows = np.arange(len(targets))
    masked = fit_probes(data.hidden, targets, rows, cfg, 0, groups, defined=defined)
    keep = np.flatnonzero(defined[:, 0])
    alone = fit_probes(
        data.hidden,
        targets[:, :1],
        keep,
        cfg,
        0,
        dataclasses.replace(groups, group=np.arange(1), scored=np.ones(1, bool)),
    )
    assert masked.cv is not None and alone.cv is not None
    np.testing.assert_allclose(masked.cv.score[:, 0], alone.cv.score[:, 0], atol=1e-6)  # type: ignore[index]
    assert masked.c is not None and alone.c is not None
    np.testing.assert_array_equal(masked.c[:, 0], alone.c[:, 0])
    np.testing.assert_allclose(masked.weight[:, :, 0], alone.weight[:, :, 0], atol=2e-3)
    plain = fit_probes(data.hidden, targets, rows, cfg, 0, groups)
    assert not np.allclose(plain.weight[:, :, 0], alone.weight[:, :, 0], atol=2e-3)


def test_masked_warm_starts_find_what_the_cold_starts_do() -> None:
    """With the mask, the warm-started C path and final fit (from the folds' mean at the chosen C) give the
    cold starts' chosen C, scores and probes (fewer iterations: test_regularization's harder problem)."""
    data = synthetic_data(num_tasks=2, episodes_per_task=4, steps_per_episode=30, num_layers=2, hidden_size=8,
                          num_object=3, num_action=0, constant_fraction=0.0, outlier_dims=0, seed=3, dtype=torch.float32)  # fmt: skip
    targets = data.labels["object"].copy()
    defined = np.ones_like(targets)
    defined[np.arange(len(targets)) % 30 < 10, 0] = False
    defined[data.episode == 0, 2] = False
    targets[~defined] = False
    groups = ColumnGroups(data.episode, data.episode_tasks, np.zeros(3, np.int64), np.ones(3, bool))
    cfg = ProbeConfig(standardize=False, c_grid=(0.01, 0.1, 1.0, 10.0), tol=1e-6, max_iter=3000, cv_folds=2)
    rows = np.arange(len(targets))
    warm, cold = (fit_probes(data.hidden, targets, rows, cfg, 0, groups, defined=defined, warm_start=w) for w in (True, False))  # fmt: skip
    assert warm.cv is not None and cold.cv is not None and warm.cv.score is not None
    np.testing.assert_array_equal(warm.cv.chosen, cold.cv.chosen)
    np.testing.assert_allclose(warm.cv.score, cold.cv.score, atol=0.005)  # type: ignore[arg-type]
    torch.testing.assert_close(warm.weight, cold.weight, atol=2e-3, rtol=0)
    torch.testing.assert_close(warm.bias, cold.bias, atol=2e-3, rtol=0)
    assert warm.convergence is not None and warm.convergence.converged.all()


def test_the_final_start_averages_only_the_folds_that_fit_a_column() -> None:
    """Column 1 is defined only on fold 0's held-out episodes: fold 1 alone fits it (on exactly its defined
    rows), so the final fit's start there is the fit of the defined rows alone at the chosen C."""
    data = synthetic_data(num_tasks=2, episodes_per_task=4, steps_per_episode=30, num_layers=2, hidden_size=8,
                          num_object=2, num_action=0, constant_fraction=0.0, outlier_dims=0, seed=3, dtype=torch.float32)  # fmt: skip
    x, rows = data.hidden.float(), np.arange(data.num_steps)
    groups = ColumnGroups(data.episode, data.episode_tasks, np.arange(2), np.ones(2, bool))
    cfg = ProbeConfig(c_grid=(0.1, 1.0), tol=1e-7, max_iter=3000, cv_folds=2)
    y = torch.as_tensor(data.labels["object"], dtype=torch.float32)
    cv, _, _ = choose_c(x, y, rows, groups, cfg, 0)
    assert cv is not None and cv.folds == 2
    defined = torch.ones_like(y)
    defined[:, 1] = torch.as_tensor(np.isin(data.episode, cv.fold_test[0]), dtype=torch.float32)
    cv, per_column, start = choose_c(x, y, rows, groups, cfg, 0, defined)
    assert start is not None
    keep = np.flatnonzero(defined[:, 1].numpy())
    w, b, _ = fit_logistic(
        x[:, keep], y[keep, 1:], torch.as_tensor(l2_of_c(per_column[:, 1:], len(keep)), dtype=torch.float32),
        tol=1e-7, max_iter=3000,
    )  # fmt: skip
    torch.testing.assert_close(start[0][:, :, 1:], w, atol=1e-3, rtol=0)
    torch.testing.assert_close(start[1][:, 1:], b, atol=1e-3, rtol=0)


def test_filter_counts_defined_rows_and_drops_what_no_row_defines() -> None:
    labels = np.array([[1, 0, 1], [0, 0, 1], [0, 1, 0], [0, 1, 1]], bool)
    defined = np.array([[1, 0, 1], [1, 0, 1], [0, 0, 1], [0, 1, 0]], bool)
    f = filter_labels([labels], ["a", "b", "c"], 0.1, 0.9, [defined], np.array([[1, 1, 0]], bool))
    assert f.kept.tolist() == [0]  # a: 1 of 2 defined rows true (all rows: 1 of 4)
    assert [(d["atom"], d["reason"]) for d in f.dropped] == [
        ("b", "train frequency 100.00% > 90%"),  # b: its one defined row is true
        ("c", "undefined in every held-out step"),
    ]
    g = filter_labels([labels], ["a", "b", "c"], 0.1, 0.9, [np.zeros_like(defined)])
    assert all(d["reason"] == "undefined in every training split" for d in g.dropped) and not len(g.kept)


# -- end to end -----------------------------------------------------------------------------------------------
def _union_data() -> ProbeData:
    """Object atom 0 names an object absent from task 0 (stored false there); atom 1 one absent everywhere."""
    data = synthetic_data(num_tasks=3, episodes_per_task=4, steps_per_episode=30, num_layers=3, hidden_size=16,
                          num_object=6, num_action=2, constant_fraction=0.0, signal=6.0, seed=4)  # fmt: skip
    absent = data.episode_tasks[data.episode] == 0
    defined = np.ones_like(data.labels["object"])
    defined[absent, 0] = False
    defined[:, 1] = False
    labels = data.labels["object"].copy()
    labels[~defined] = False
    return dataclasses.replace(data, labels={**data.labels, "object": labels}, defined={"object": defined})


def test_training_on_a_union_store_scores_the_defined_entries_only(tmp_path: Path) -> None:
    data = _union_data()
    cfg = TrainConfig(bootstrap=50, auprc_bootstrap=10, conditional=True, probe=ProbeConfig(c_grid=(1.0,)))
    ev = read_evaluation(train_on_data(data, cfg, tmp_path / "masked"))
    plain = read_evaluation(train_on_data(dataclasses.replace(data, defined={}), cfg, tmp_path / "plain"))
    head = ev.heads["object"]
    names = data.atom_names["object"]
    assert names[1] not in head.atoms and names[0] in head.atoms
    assert [d.atom for d in head.dropped if d.reason.startswith("undefined")] == [names[1]]
    test = np.isin(data.episode, [data.episode_keys.index(k) for k in ev.split.test_episodes])
    kept = data.defined["object"][test, 0]
    assert head.test_frequency[0] == pytest.approx(data.labels["object"][test, 0][kept].mean())
    assert kept.sum() < test.sum()  # task 0's test rows are left out
    at = plain.heads["object"].atoms.index(names[0])
    masked_ba = head.probe["balanced_accuracy"].atom.value
    plain_ba = plain.heads["object"].probe["balanced_accuracy"].atom.value
    assert [row[0] for row in masked_ba] != [row[at] for row in plain_ba]  # the mask changed atom 0's figures
    assert head.matched is not None and head.conditional_task is not None


def test_an_all_defined_mask_gives_the_figures_of_no_mask(tmp_path: Path) -> None:
    """A LIBERO-spatial store: ``load_store`` fills an all-true mask, which must change nothing."""
    data = synthetic_data(
        num_tasks=2, episodes_per_task=3, steps_per_episode=20, num_layers=2, hidden_size=8, seed=5
    )
    full = {h: np.ones_like(y) for h, y in data.labels.items()}
    cfg = TrainConfig(bootstrap=30, auprc_bootstrap=5)
    a = json.loads((train_on_data(data, cfg, tmp_path / "a") / "evaluation.json").read_text())
    b = json.loads(
        (
            train_on_data(dataclasses.replace(data, defined=full), cfg, tmp_path / "b") / "evaluation.json"
        ).read_text()
    )
    a.pop("seconds"), b.pop("seconds")
    assert a == b
