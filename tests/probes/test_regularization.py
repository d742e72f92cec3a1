"""The C search: balanced-accuracy fold scores (checked against scikit-learn), the tie rule, the edge flag."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from vlaprobe.configs.train import ProbeConfig, TrainConfig
from vlaprobe.probes import synthetic_data, train_on_data
from vlaprobe.probes.regularization import ColumnGroups, CrossValidation, choose_c, select_c
from vlaprobe.probes.results import read_evaluation
from vlaprobe.probes.trainer import fit_probes, training_matrix

GRID = (1e-4, 1e-3, 1e-2, 0.1, 1.0, 10.0, 100.0)


def test_select_c_takes_the_strongest_penalty_within_the_tolerance() -> None:
    grid = [0.01, 0.1, 1.0, 10.0]
    score = np.array(
        [
            [0.5, 0.80, 0.84, 0.843],  # 0.84 is within 0.005 of 0.843: the smaller C
            [0.5, 0.90, 0.80, 0.70],  # a clear interior optimum
            [0.5, 0.5, 0.5, 0.5],  # all tied: the strongest penalty (an edge)
            [np.nan, 0.6, np.nan, 0.7],  # undefined entries are skipped
            [np.nan] * 4,  # nothing defined: the largest C
        ]
    )
    assert select_c(score, grid, 0.005).tolist() == [1.0, 0.1, 0.01, 10.0, 10.0]
    assert select_c(score, grid, 0.0)[0] == 10.0


def _problem(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, np.ndarray, ColumnGroups]:
    """Two Gaussian classes (45 % positives) along a random direction in 80 dimensions, 160 training rows per
    fold: the strongest penalties predict the majority (0.5), the weakest over-fit near the separability
    threshold, the optimum is inside the grid (scikit-learn agrees, below)."""
    rng = np.random.default_rng(seed)
    episodes, steps, hidden, atoms, p = 12, 20, 80, 3, 0.45
    n = episodes * steps
    y = rng.random((n, atoms)) < p
    u = rng.normal(size=(atoms, hidden))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    x = rng.normal(size=(2, n, hidden)) + 2.0 * ((y - p) @ u)[None]
    x[1] += 0.5 * rng.normal(size=(n, hidden))  # a second layer, noisier
    xt, _, _ = training_matrix(
        torch.as_tensor(x, dtype=torch.float32), np.arange(n), torch.device("cpu"), True
    )
    groups = ColumnGroups(
        episode=np.repeat(np.arange(episodes), steps),
        episode_tasks=np.repeat(np.arange(3), episodes // 3),
        group=np.zeros(atoms, np.int64),
        scored=np.ones(atoms, bool),
    )
    return xt, torch.as_tensor(y, dtype=torch.float32), np.arange(n), groups


@pytest.fixture(scope="module")
def searched() -> tuple[CrossValidation, np.ndarray, tuple]:
    x, y, rows, groups = _problem()
    cfg = ProbeConfig(device="cpu", c_grid=GRID, cv_folds=3, tol=1e-5, max_iter=1000)
    cv, per_column, _ = choose_c(x, y, rows, groups, cfg, seed=0)
    assert cv is not None
    return cv, per_column, (x, y, rows, groups)


def test_a_known_optimum_inside_the_grid_is_chosen_and_not_flagged(searched: tuple) -> None:
    cv, per_column, _ = searched
    assert cv.score is not None and cv.score.shape == (2, 1, len(GRID)) and cv.folds == 3
    score = cv.score[:, 0]
    chosen = cv.of_group(0)[1]
    assert ((chosen > GRID[0]) & (chosen < GRID[-1])).all(), chosen
    assert not cv.edge_of(0).any()
    at = np.searchsorted(GRID, chosen)
    for layer in range(2):  # the chosen C beats both ends of the grid clearly
        assert score[layer, at[layer]] > max(score[layer, 0], score[layer, -1]) + 0.02, score[layer]
        assert score[layer, at[layer]] >= np.nanmax(score[layer]) - cv.tolerance
    assert (per_column == chosen[:, None]).all()


def test_fold_scores_are_scikit_learns_balanced_accuracy(searched: tuple) -> None:
    sklearn = pytest.importorskip("sklearn")
    from sklearn.linear_model import LogisticRegression
    from sklearn.metrics import balanced_accuracy_score

    assert sklearn
    cv, _, (x, y, _, groups) = searched
    assert cv.score is not None
    truth = y.numpy() > 0.5
    ours = cv.score[:, 0]
    theirs = np.empty_like(ours)
    for layer in range(x.shape[0]):
        for j, c in enumerate(GRID):
            per_fold = []
            for held in cv.fold_test:
                test = np.isin(groups.episode, held)
                xs = x[layer].numpy().astype(np.float64)
                per_atom = []
                for a in range(truth.shape[1]):
                    model = LogisticRegression(C=c, tol=1e-8, max_iter=5000).fit(xs[~test], truth[~test, a])
                    per_atom.append(balanced_accuracy_score(truth[test, a], model.predict(xs[test])))
                per_fold.append(np.mean(per_atom))
            theirs[layer, j] = np.mean(per_fold)
    # Held-out sets of ~80 rows: one row that falls on the other side moves an atom's figure by ~0.01.
    np.testing.assert_allclose(ours, theirs, atol=0.01)
    sk_chosen = select_c(theirs, list(GRID), cv.tolerance)
    assert (sk_chosen == cv.of_group(0)[1]).all(), (ours, theirs)


def test_a_choice_at_the_edge_is_flagged_warned_and_recorded(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    data = synthetic_data(
        num_tasks=3, episodes_per_task=4, steps_per_episode=20, num_layers=2, hidden_size=16, signal=8.0
    )
    grid = (1e-6, 1e-5, 1e-4)  # far too strong a penalty for a strong signal
    cfg = TrainConfig(shuffled_control=False, bootstrap=20, auprc_bootstrap=0, probe=ProbeConfig(c_grid=grid))
    with caplog.at_level("WARNING", logger="vlaprobe.probes"):
        out = train_on_data(data, cfg, tmp_path)
    for head in ("object", "action"):
        fit = read_evaluation(out).heads[head].fit
        assert fit is not None and fit.c_at_edge == [True, True] and set(fit.c) <= {1e-6, 1e-4}
        assert np.array(fit.cv_score, float).shape == (2, 3) and "balanced accuracy" in fit.c_rule
        message = fit.edge_warning(head)
        assert message is not None and f"{head}: C at the edge of its grid" in message
        assert message in caplog.text and "widen --probe.c-grid" in message
    from vlaprobe.reports.report import _tables  # the report's page shows the same line under the headline

    tables = _tables(read_evaluation(out))
    assert all(tables[h]["c_warning"] == read_evaluation(out).heads[h].fit.edge_warning(h) for h in tables)  # type: ignore[union-attr]
    raw = json.loads((out / "evaluation.json").read_text())
    assert raw["heads"]["object"]["fit"]["c_at_edge"] == [True, True]


def test_an_evaluation_without_the_new_fields_still_reads(tmp_path: Path) -> None:
    data = synthetic_data(
        num_tasks=2, episodes_per_task=3, steps_per_episode=20, num_layers=2, hidden_size=16, signal=8.0
    )
    cfg = TrainConfig(
        shuffled_control=False, bootstrap=5, auprc_bootstrap=0, probe=ProbeConfig(c_grid=(0.1,))
    )
    out = train_on_data(data, cfg, tmp_path)
    path = out / "evaluation.json"
    raw = json.loads(path.read_text())
    fit = raw["heads"]["object"]["fit"]
    assert fit["c_at_edge"] is None and fit["cv_score"] is None  # one C: nothing cross-validated
    for key in ("c_at_edge", "cv_score", "c_rule"):
        del fit[key]
    path.write_text(json.dumps(raw))
    read = read_evaluation(out).heads["object"].fit
    assert read is not None and read.c_at_edge is None and read.edge_warning("object") is None
    assert math.isclose(float(read.c[0]), 0.1)


def test_one_training_episode_per_task_skips_the_search_with_a_warning() -> None:
    x, y, rows, groups = _problem()
    one_each = dataclasses.replace(groups, episode_tasks=np.arange(12))  # 12 tasks, one episode each
    cfg = ProbeConfig(device="cpu", c_grid=GRID, cv_folds=3, c_without_cv=0.3)
    cv, per_column, _ = choose_c(x, y, rows, one_each, cfg, seed=0)
    assert cv is None and (per_column == 0.3).all()
    # the same data with the tasks shared by 4 episodes each is searched
    assert choose_c(x, y, rows, groups, cfg, seed=0)[0] is not None


def test_train_warns_and_records_when_one_episode_per_task_leaves_nothing_to_hold_out(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    data = synthetic_data(
        num_tasks=3, episodes_per_task=2, steps_per_episode=20, num_layers=2, hidden_size=16
    )
    cfg = TrainConfig(shuffled_control=False, bootstrap=5, auprc_bootstrap=0, probe=ProbeConfig(c_grid=GRID))
    with caplog.at_level("WARNING", logger="vlaprobe.probes"):
        out = train_on_data(data, cfg, tmp_path)
    fit = read_evaluation(out).heads["object"].fit
    assert fit is not None and set(fit.c) == {1.0} and fit.c_at_edge is None and fit.cv_folds == 0
    message = fit.edge_warning("object")
    assert message is not None and "--probe.c-without-cv" in message and "3 episodes per task" in message
    assert message in caplog.text


def _search_iterations(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """A list that the C search's solver calls append their iteration totals to."""
    from vlaprobe.probes import lbfgs, regularization

    counts: list[int] = []

    def counted(*args: Any, **kwargs: Any) -> tuple[torch.Tensor, torch.Tensor, lbfgs.Convergence]:
        w, b, conv = lbfgs.fit_logistic(*args, **kwargs)
        counts.append(int(conv.iterations.sum()))
        return w, b, conv

    monkeypatch.setattr(regularization, "fit_logistic", counted)
    return counts


def test_warm_starts_change_where_the_solver_starts_not_what_it_finds(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Along the C path (each fold from its solution at the C before) and for the final fit (from the folds'
    mean at the chosen C): the same scores, chosen C and probes as fits from the cold start, in fewer
    iterations. The shuffled copies are not searched: their final fit starts cold either way."""
    x, y, rows, groups = _problem()
    k = y.shape[1]
    shuffled = y[torch.as_tensor(np.random.default_rng(1).permutation(len(rows)))]
    targets = torch.cat([y, shuffled], 1).numpy()
    both = dataclasses.replace(groups, group=np.zeros(2 * k, np.int64), scored=np.arange(2 * k) < k)
    cfg = ProbeConfig(device="cpu", c_grid=GRID, cv_folds=3, tol=1e-5, max_iter=1000)
    fits, counts = {}, {}
    for warm in (False, True):
        counts[warm] = _search_iterations(monkeypatch)
        fits[warm] = fit_probes(x, targets, rows, cfg, seed=0, groups=both, warm_start=warm)
    cold, warm = fits[False], fits[True]
    assert (
        cold.cv is not None
        and warm.cv is not None
        and cold.cv.score is not None
        and warm.cv.score is not None
    )
    assert cold.convergence is not None and warm.convergence is not None
    assert cold.convergence.converged.all() and warm.convergence.converged.all()
    chosen = warm.cv.of_group(0)[1]
    assert ((chosen > GRID[0]) & (chosen < GRID[-1])).all()  # the known optimum inside the grid
    np.testing.assert_array_equal(cold.cv.chosen, warm.cv.chosen)
    # A held-out row within round-off of the threshold may fall on either side: one row moves a fold's score
    # by ~0.002 here.
    np.testing.assert_allclose(warm.cv.score, cold.cv.score, atol=0.005)
    # At the weakest penalties a gradient within tol leaves the weights free by up to ~tol / l2 along flat
    # directions (C = 100: l2 = 6e-5 here): the held-out log-loss there agrees to ~0.2 %.
    np.testing.assert_allclose(warm.cv.loss, cold.cv.loss, rtol=0.005)
    torch.testing.assert_close(warm.weight, cold.weight, atol=1e-3, rtol=0)  # (weights up to ~1)
    torch.testing.assert_close(warm.bias, cold.bias, atol=1e-3, rtol=0)
    assert sum(counts[True]) < 0.9 * sum(counts[False]), counts
    its = warm.convergence.iterations, cold.convergence.iterations
    assert its[0][:, :k].sum() < 0.8 * its[1][:, :k].sum(), its  # the searched columns
    assert (its[0][:, k:] == its[1][:, k:]).all()  # the shuffled ones: the same cold start
