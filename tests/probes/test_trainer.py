"""The batched trainer: planted structure recovered, controls at chance, converged, C chosen by grouped CV."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from vlaprobe.configs.train import ProbeConfig
from vlaprobe.probes.data import synthetic_data
from vlaprobe.probes.regularization import ColumnGroups
from vlaprobe.probes.split import filter_labels, rows_of, split_episodes
from vlaprobe.probes.trainer import fit_probes

NOISE = 0.05


@pytest.fixture(scope="module")
def planted() -> dict:
    data = synthetic_data(
        num_tasks=4,
        episodes_per_task=8,
        steps_per_episode=40,
        num_layers=5,
        hidden_size=64,
        num_object=18,
        num_action=4,
        label_noise=NOISE,
        signal=8.0,
        seed=0,
    )
    (fold,) = split_episodes(data.episode_tasks, 0.25, 1, seed=0)
    train, test = rows_of(data.episode, fold.train), rows_of(data.episode, fold.test)
    y = np.concatenate([data.labels["object"], data.labels["action"]], 1)
    y = y[:, filter_labels(y[train], [str(i) for i in range(y.shape[1])], 0.01, 0.99).kept]
    return {"data": data, "train": train, "test": test, "y": y}


def accuracy(logits: torch.Tensor, truth: np.ndarray) -> np.ndarray:
    """Mean accuracy per layer over atoms."""
    return ((logits > 0) == torch.from_numpy(truth)).float().mean(dim=(1, 2)).numpy()


def test_planted_labels_recovered_while_shuffled_labels_stay_at_majority(planted: dict) -> None:
    data, train, test, y = planted["data"], planted["train"], planted["test"], planted["y"]
    rng = np.random.default_rng(0)
    shuffled = y.copy()
    shuffled[train] = y[rng.permutation(train)]
    k = y.shape[1]
    probes = fit_probes(
        data.hidden, np.concatenate([y, shuffled], 1), train, ProbeConfig(device="cpu"), seed=0, c=1.0
    )
    logits = probes.logits(data.hidden, test)
    real, control = accuracy(logits[:, :, :k], y[test]), accuracy(logits[:, :, k:], y[test])
    majority = float((y[test] == (y[train].mean(0) >= 0.5)).mean())
    # Best possible: predict the clean label, wrong exactly on the flipped NOISE share.
    assert real.max() >= 1 - NOISE - 0.025
    assert real.max() <= 1 - NOISE + 0.02
    assert int(real.argmax()) in (1, 2, 3) and real[0] < real.max() - 0.05  # the planted layer profile
    assert np.all(np.abs(control - majority) < 0.04), (control, majority)
    assert real.max() > majority + 0.2


def test_all_layers_at_once_equal_each_layer_alone(planted: dict) -> None:
    data, train, y = planted["data"], planted["train"], planted["y"]
    cfg = ProbeConfig(device="cpu", tol=1e-5)
    together = fit_probes(data.hidden, y, train, cfg, seed=3, c=0.1)
    for layer in (0, 3):
        alone = fit_probes(data.hidden[layer : layer + 1], y, train, cfg, seed=3, c=0.1)
        torch.testing.assert_close(alone.weight[0], together.weight[layer], atol=2e-3, rtol=1e-2)
        torch.testing.assert_close(alone.bias[0], together.bias[layer], atol=2e-3, rtol=1e-2)


def test_extra_columns_do_not_change_the_others(planted: dict) -> None:
    data, train, y = planted["data"], planted["train"], planted["y"]
    cfg = ProbeConfig(device="cpu")
    alone = fit_probes(data.hidden, y, train, cfg, seed=1, c=0.1)
    wide = fit_probes(data.hidden, np.concatenate([y, ~y], 1), train, cfg, seed=1, c=0.1)
    # Each column runs its own L-BFGS: the extra columns do not change a single step of the others.
    torch.testing.assert_close(wide.weight[:, :, : y.shape[1]], alone.weight, atol=1e-5, rtol=1e-4)


def test_standardize_makes_probes_blind_to_feature_scale(planted: dict) -> None:
    data, train, test, y = planted["data"], planted["train"], planted["test"], planted["y"]
    scale = torch.exp(torch.randn(data.hidden_size, generator=torch.Generator().manual_seed(0)) * 2)
    scaled = (data.hidden.float() * scale).to(torch.float32)
    plain = data.hidden.float()
    cfg = ProbeConfig(device="cpu", standardize=True)
    a = fit_probes(plain, y, train, cfg, seed=0, c=0.1).logits(plain, test)
    b_probes = fit_probes(scaled, y, train, cfg, seed=0, c=0.1)
    b = b_probes.logits(scaled, test)
    torch.testing.assert_close(a, b, atol=5e-3, rtol=5e-3)
    assert b_probes.mean is not None and b_probes.std is not None
    raw = fit_probes(
        scaled, y, train, dataclasses.replace(cfg, standardize=False, max_iter=30), seed=0, c=0.1
    ).logits(scaled, test)
    assert (raw - a).abs().max() > 0.1  # without it the scale does matter


def test_balance_raises_recall_of_rare_atoms(planted: dict) -> None:
    data, train, y = planted["data"], planted["train"], planted["y"]
    rare = np.argsort(y[train].mean(0))[:4]  # the four rarest atoms
    assert y[train].mean(0)[rare].max() < 0.4
    hidden = data.hidden[:1]  # the weakest layer: mistakes to trade
    plain = fit_probes(hidden, y, train, ProbeConfig(device="cpu"), seed=0, c=0.1).logits(hidden, train)
    balanced = fit_probes(hidden, y, train, ProbeConfig(device="cpu", balance=True), seed=0, c=0.1).logits(
        hidden, train
    )
    truth = torch.from_numpy(y[train][:, rare])

    def recall(logits: torch.Tensor) -> float:
        pred = logits[0][:, rare] > 0
        return float((pred & truth).sum() / truth.sum())

    assert recall(balanced) > recall(plain) + 0.05


def test_every_probe_converges_to_the_tolerance_or_is_counted_at_the_cap(planted: dict) -> None:
    data, train, y = planted["data"], planted["train"], planted["y"]
    probes = fit_probes(data.hidden, y, train, ProbeConfig(device="cpu", tol=1e-4), seed=0, c=1.0)
    conv = probes.convergence
    assert conv is not None and conv.converged.all() and conv.grad_norm.max() <= 1e-4
    assert conv.iterations.shape == (5, y.shape[1]) and conv.iterations.min() > 0
    capped = fit_probes(
        data.hidden, y, train, ProbeConfig(device="cpu", max_iter=2), seed=0, c=1.0
    ).convergence
    assert capped is not None and not capped.converged.any() and (capped.iterations == 2).all()
    assert (capped.loss > conv.loss - 1e-6).all()  # the converged objective is lower everywhere


def test_cross_validation_picks_a_strong_penalty_for_noise_and_a_weak_one_for_signal() -> None:
    data = synthetic_data(
        num_tasks=3,
        episodes_per_task=6,
        steps_per_episode=30,
        num_layers=2,
        hidden_size=32,
        num_object=6,
        num_action=2,
        signal=8.0,
        label_noise=0.0,
        seed=1,
    )
    rng = np.random.default_rng(0)
    y = np.concatenate([data.labels["object"], data.labels["action"]], 1)
    y = y[:, (y.mean(0) > 0.05) & (y.mean(0) < 0.95)]
    noise = rng.random(y.shape) < 0.3  # labels that the hidden states say nothing about
    targets = np.concatenate([y, noise], 1)
    k = y.shape[1]
    groups = ColumnGroups(
        episode=data.episode,
        episode_tasks=data.episode_tasks,
        group=np.repeat([0, 1], k),
        scored=np.ones(2 * k, bool),
    )
    cfg = ProbeConfig(device="cpu", c_grid=(0.001, 0.1, 10.0), cv_folds=3)
    probes = fit_probes(data.hidden, targets, np.arange(data.num_steps), cfg, seed=0, groups=groups)
    assert probes.cv is not None and probes.cv.folds == 3 and probes.cv.loss.shape == (2, 2, 3)
    signal_c, noise_c = probes.cv.of_group(0)[1], probes.cv.of_group(1)[1]
    assert (noise_c == 0.001).all() and (signal_c > 0.001).all(), (signal_c, noise_c)
    assert probes.c is not None and (probes.c[:, k:] == 0.001).all()
    with pytest.raises(ValueError, match="episodes"):
        fit_probes(data.hidden, targets, np.arange(data.num_steps), cfg, seed=0)


def test_backtracking_columns_alone_give_the_same_probes(
    planted: dict, monkeypatch: pytest.MonkeyPatch
) -> None:
    from vlaprobe.probes import lbfgs

    data, train, y = planted["data"], planted["train"], planted["y"]
    x = data.hidden[:2, train].float() * 5  # unstandardised, large features: step 1 often overshoots
    x -= x.mean(1, keepdim=True)
    targets = torch.as_tensor(y[train], dtype=torch.float32)
    l2 = torch.full((2, y.shape[1]), 1e-2)
    widths: list[int] = []
    data_change = lbfgs._Problem.data_change  # the line search's trial

    def counting(self: lbfgs._Problem, z: torch.Tensor, *rest: torch.Tensor) -> torch.Tensor:
        widths.append(z.shape[-1])
        return data_change(self, z, *rest)

    monkeypatch.setattr(lbfgs._Problem, "data_change", counting)
    *_, conv = lbfgs.fit_logistic(x, targets, l2, tol=1e-7, max_iter=300)
    assert not conv.converged.any()  # so no column left the working set: every narrower pass was a halving
    assert min(widths) < y.shape[1]  # some halvings went on with the pending columns only
    for j in (0, y.shape[1] - 1):
        *_, alone = lbfgs.fit_logistic(x, targets[:, j : j + 1], l2[:, j : j + 1], tol=1e-7, max_iter=300)
        np.testing.assert_allclose(alone.loss[:, 0], conv.loss[:, j], rtol=1e-5)


def test_the_line_search_measures_the_change_of_the_loss_not_a_difference_of_two_losses() -> None:
    from vlaprobe.probes import lbfgs

    softplus = torch.nn.functional.softplus
    gen = torch.Generator().manual_seed(0)
    n, k = 500, 4
    y = (torch.rand((n, k), generator=gen) < 0.3).float()
    z = 3 * torch.randn((1, n, k), generator=gen)
    prob = lbfgs._Problem(
        torch.zeros((1, n, 1)), y, None, torch.full((k,), 1.0 / n), torch.ones((1, k)), torch.zeros((1, 1, 1))
    )
    # per column its own step: a column with |delta| > 1 on some rows sits next to columns without
    step = torch.tensor([[1.0, 0.5, 1e-3, 2.0]])
    for scale in (1e-6, 1e-2, 3.0):  # tiny steps near a minimum, ordinary ones, and |delta| > 1
        dz = scale * torch.randn((1, n, k), generator=gen)
        delta = dz * step[:, None]
        zd, dd = z.double(), delta.double()
        exact = (softplus(zd + dd) - softplus(zd) - y.double() * dd).sum(1) / n
        ydz, dz_max = prob.target_dot(dz), dz.abs().amax(1)
        ours = prob.data_change(z, torch.sigmoid(z), dz, step, ydz, dz_max).double()
        np.testing.assert_allclose(ours, exact, rtol=1e-4)
        if scale == 1e-6:  # where the difference of two float32 losses is mostly round-off
            naive = (prob.data_loss(z + delta) - prob.data_loss(z)).double()
            assert (abs(naive - exact) > 0.05 * abs(exact)).any()


def test_the_fit_does_not_depend_on_the_number_of_torch_threads() -> None:
    """On a CPU the layers run side by side, one thread each: any thread count gives the same bits (large
    enough that torch would split a reduction over rows between threads)."""
    from vlaprobe.probes import lbfgs

    gen = torch.Generator().manual_seed(0)
    x = torch.randn((3, 4000, 16), generator=gen)
    truth = torch.randn((16, 24), generator=gen)
    targets = ((x[0] @ truth + torch.randn((4000, 24), generator=gen)) > 0).float()
    l2 = torch.full((3, 24), 1e-3)
    threads = torch.get_num_threads()
    fits = []
    try:
        for n in (1, 3):
            torch.set_num_threads(n)
            fits.append(lbfgs.fit_logistic(x, targets, l2, tol=1e-6, max_iter=300))
    finally:
        torch.set_num_threads(threads)
    (w1, b1, c1), (w3, b3, c3) = fits
    assert torch.get_num_threads() == threads  # the count restored
    assert torch.equal(w1, w3) and torch.equal(b1, b3) and np.array_equal(c1.iterations, c3.iterations)


def test_a_per_feature_penalty_leaves_the_free_features_unpenalised(planted: dict) -> None:
    from vlaprobe.probes import lbfgs

    data, train, y = planted["data"], planted["train"], planted["y"]
    x = data.hidden[:2, train].float()
    x = (x - x.mean(1, keepdim=True)) / x.std(1, keepdim=True)
    targets = torch.as_tensor(y[train], dtype=torch.float32)
    l2 = torch.full((2, y.shape[1]), 0.05)
    w_all, b_all, _ = lbfgs.fit_logistic(x, targets, l2, tol=1e-6, max_iter=1000)
    ones = torch.ones(x.shape[2])
    w_ones, b_ones, _ = lbfgs.fit_logistic(x, targets, l2, tol=1e-6, max_iter=1000, penalized=ones)
    assert torch.equal(w_all, w_ones) and torch.equal(b_all, b_ones)  # all 1: the plain penalty, bit for bit
    free = ones.clone()
    free[:8] = 0
    w, b, conv = lbfgs.fit_logistic(x, targets, l2, tol=1e-6, max_iter=1000, penalized=free)
    assert conv.converged.all()
    # Optimality, from the objective's definition: the data term's gradient is 0 on the free features and
    # -l2 w on the penalised ones.
    z = torch.einsum("lnh,lhk->lnk", x.double(), w.double()) + b.double()[:, None]
    grad = torch.einsum("lnh,lnk->lhk", x.double(), torch.sigmoid(z) - targets.double()) / len(train)
    np.testing.assert_allclose(grad[:, :8], 0, atol=2e-6)
    np.testing.assert_allclose(grad[:, 8:], -0.05 * w.double()[:, 8:], atol=2e-6)
    assert (w[:, :8].abs().mean() > w_all[:, :8].abs().mean()).item()  # freed weights grow
