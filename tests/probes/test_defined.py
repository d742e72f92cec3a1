"""Undefined entries (union stores): weight 0 in fit_logistic is fitting on the defined rows only."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vlaprobe.probes.data import synthetic_data
from vlaprobe.probes.lbfgs import fit_logistic, l2_of_c


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
