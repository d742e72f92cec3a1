"""Many independent L2-regularised logistic regressions solved at once by a batched L-BFGS.

Every (layer, column) pair is its own binary logistic regression with objective

    f(w, b) = sum_i s_i [softplus(z_i) - y_i z_i] / n  +  (l2 / 2) sum_j m_j w_j^2,     z_i = x_i . w + b

(``s_i``: row weights, e.g. a fold's membership or class balancing; ``n``: the rows that count; the bias is
not penalised, nor the features with ``m_j = 0``; by default every ``m_j`` is 1). With ``l2 = 1 / (C n)`` this is scikit-learn's ``LogisticRegression(C=C)`` divided by
``C n``: the same minimiser. The problems never interact, but they share the data, so one ``baddbmm`` gives
every column's logits and one ``bmm`` every weight gradient. Each column runs its own L-BFGS (its own
history, step length and stopping point): the two-loop recursion is a handful of per-column dot products,
and the Armijo backtracking line search costs no matmul, because the logits are linear in the step length
(``z + a dz``). A column stops when the largest absolute entry of its gradient is at most ``tol`` (the
criterion of scikit-learn's lbfgs), or at ``max_iter`` iterations. Layers are processed in chunks that fit
a memory budget.

The solver works on features centred per column (on the column's weighted rows: a fold's training rows, say)
and converts the bias back at the end, ``b = b' - mean . w``: the same minimiser (the bias is not
penalised), but without the coupling of weights and bias that a fold's off-centre rows bring, which made the
strongly penalised fold problems of the C search ill-conditioned (hundreds of iterations instead of a few).
The line search's Armijo test compares the change of the objective, computed per row to its own precision
(:meth:`_Problem.data_change`), not a difference of two float32 objectives.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F


@dataclass
class Convergence:
    """Where each (layer, column) problem stopped."""

    iterations: np.ndarray
    """int (layers, columns): L-BFGS iterations run."""
    loss: np.ndarray
    """(layers, columns): final objective (weighted mean log-loss + L2 term)."""
    grad_norm: np.ndarray
    """(layers, columns): final largest absolute gradient entry."""
    converged: np.ndarray
    """bool (layers, columns): stopped with ``grad_norm <= tol`` (else at the cap or a failed line search)."""
    tol: float
    max_iter: int

    def columns(self, cols: np.ndarray | slice) -> Convergence:
        """The same figures for some columns only."""
        return Convergence(
            self.iterations[:, cols],
            self.loss[:, cols],
            self.grad_norm[:, cols],
            self.converged[:, cols],
            self.tol,
            self.max_iter,
        )


@dataclass
class _Problem:
    """One layer chunk's data: features, targets, row weights, normalisers and penalties."""

    x: torch.Tensor  # (L, n, H)
    y: torch.Tensor  # (n, K)
    weight: torch.Tensor | None  # (n, K) row weights, or None (all 1)
    inv_n: torch.Tensor  # (K,) 1 / rows that count
    l2: torch.Tensor  # (L, K)
    center: torch.Tensor  # (L, K or 1, H) each column's weighted feature mean
    penalized: torch.Tensor | None = None  # (H,) 1 for a penalised feature, 0 for a free one; None: all 1
    share: torch.Tensor = field(init=False)  # (n, K) or (K,): set from weight and inv_n

    def __post_init__(self) -> None:
        # Each row's share of its column's mean loss: the row weight over the rows that count (one factor,
        # so that every per-row pass of the loss and the gradient multiplies once).
        self.share = self.inv_n if self.weight is None else self.weight * self.inv_n

    def penalized_part(self, w: torch.Tensor) -> torch.Tensor:
        """``w`` (..., H) with the free features' entries zeroed: what the L2 term sees."""
        return w if self.penalized is None else w * self.penalized

    def logits(self, p: torch.Tensor) -> torch.Tensor:
        """(L, n, K) logits of parameters ``p`` (L, K, H + 1), the bias last, on centred features:
        ``(x - center) . w + b`` (see :func:`fit_logistic`)."""
        w = p[:, :, :-1]
        return torch.baddbmm((p[:, :, -1] - _dot(self.center, w))[:, None], self.x, w.transpose(1, 2))

    def data_loss(self, z: torch.Tensor) -> torch.Tensor:
        loss = F.softplus(z) - self.y * z
        return loss.mul_(self.share).sum(1)

    def target_dot(self, dz: torch.Tensor) -> torch.Tensor:
        """(L, K) the weighted mean of ``y dz`` over the rows: the linear part of the loss's change along
        ``dz``, which :meth:`data_change` takes scaled by the step instead of a pass per trial."""
        return (self.y * dz).mul_(self.share).sum(1)

    def data_change(
        self,
        z: torch.Tensor,
        sig: torch.Tensor,
        dz: torch.Tensor,
        step: torch.Tensor,
        ydz: torch.Tensor,
        dz_max: torch.Tensor,
    ) -> torch.Tensor:
        """``data_loss(z + step dz) - data_loss(z)`` (``sig`` = sigmoid(z), ``ydz`` = :meth:`target_dot`,
        ``dz_max`` (L, K) each column's largest ``|dz|``), accurate relative to the change: per row
        log1p(sig expm1(delta)) - y delta, delta = step dz, where |delta| < 1. Subtracting two float32 losses
        cannot resolve the tiny decreases near the minimum of a strongly penalised problem, where the line
        search then accepted steps that did not lower the objective and ran to the iteration cap. Where
        |delta| >= 1 (only in the columns where ``step dz_max`` reaches 1) the softplus difference is exact
        enough, and expm1 could overflow."""
        delta = dz * step[:, None]
        change = torch.expm1(delta).mul_(sig).log1p_()
        large = torch.nonzero((step * dz_max >= 1).any(0)).flatten()
        if len(large):  # (near the minimum the steps are small: no softplus pass at all)
            zl, dl = z.index_select(2, large), delta.index_select(2, large)
            exact = F.softplus(zl + dl).sub_(F.softplus(zl))
            change.index_copy_(2, large, torch.where(dl.abs() < 1, change.index_select(2, large), exact))
        return change.mul_(self.share).sum(1).sub_(step * ydz)

    def gradient(self, z: torch.Tensor, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(gradient at ``p``, sigmoid(z)): the line search from ``p`` reuses the latter."""
        sig = torch.sigmoid(z)
        r = (sig - self.y).mul_(self.share)
        g = torch.empty_like(p)
        torch.bmm(r.transpose(1, 2), self.x, out=g[:, :, :-1])
        g[:, :, -1] = r.sum(1)
        g[:, :, :-1].sub_(self.center * g[:, :, -1:])
        g[:, :, :-1].add_(self.penalized_part(p[:, :, :-1]) * self.l2[..., None])
        return g, sig

    def penalty(self, p: torch.Tensor) -> torch.Tensor:
        w = p[:, :, :-1]
        return 0.5 * self.l2 * _dot(self.penalized_part(w), w)

    def select(self, keep: torch.Tensor) -> _Problem:
        """The same problem for the columns ``keep`` (an index tensor) only; the features are shared."""
        weight = None if self.weight is None else self.weight.index_select(1, keep)
        center = self.center if self.center.shape[1] == 1 else self.center.index_select(1, keep)
        return _Problem(
            self.x,
            self.y.index_select(1, keep),
            weight,
            self.inv_n[keep],
            self.l2.index_select(1, keep),
            center,
            self.penalized,
        )


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(-1)


def _direction(
    g: torch.Tensor, hist: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]], gamma: torch.Tensor
):
    """The L-BFGS two-loop recursion, per column; pairs with rho 0 (no curvature) contribute nothing."""
    q = g.clone()
    alphas = []
    for s, yv, rho in reversed(hist):
        a = rho * _dot(s, q)
        q.sub_(a[..., None] * yv)
        alphas.append(a)
    q.mul_(gamma[..., None])
    for (s, yv, rho), a in zip(hist, reversed(alphas), strict=True):
        q.add_((a - rho * _dot(yv, q))[..., None] * s)
    return q.neg_()


def _line_search(
    prob: _Problem,
    p: torch.Tensor,
    d: torch.Tensor,
    z: torch.Tensor,
    sig: torch.Tensor,
    f: torch.Tensor,
    gd: torch.Tensor,
    step: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per-column Armijo backtracking from ``step`` (``sig``: sigmoid(z)).

    Returns (accepted step, 0 where none was found; the objective there, ``f`` where none; logits dz).
    The first trial covers every column; the later ones only the columns still pending (usually few), so
    that a backtracking column does not cost a pass over every column's logits.
    """
    dz = prob.logits(d)
    ydz, dz_max = prob.target_dot(dz), dz.abs().amax(1)
    pw, dw = prob.penalized_part(p[:, :, :-1]), d[:, :, :-1]
    wd, dd = _dot(pw, dw), _dot(prob.penalized_part(dw), dw)
    pending = gd < 0
    accepted = torch.zeros_like(step)
    f_new = f.clone()
    cols = torch.arange(step.shape[1], device=step.device)
    sub, zs, sigs, dzs, f_ref = prob, z, sig, dz, f
    for trial_index in range(40):
        if not bool(pending.any()):
            break
        if trial_index == 1:  # from now on, the pending columns only
            cols = torch.nonzero(pending.any(0)).flatten()
            sub, zs, dzs = prob.select(cols), z.index_select(2, cols), dz.index_select(2, cols)
            sigs = sig.index_select(2, cols)
            wd, dd, f_ref, gd = wd[:, cols], dd[:, cols], f[:, cols], gd[:, cols]
            ydz, dz_max = ydz[:, cols], dz_max[:, cols]
            step, pending = step[:, cols], pending[:, cols]
        # The change of the objective, not the objective: see _Problem.data_change.
        change = sub.data_change(zs, sigs, dzs, step, ydz, dz_max) + 0.5 * sub.l2 * step * (
            2 * wd + step * dd
        )
        ok = pending & (change <= 1e-4 * step * gd)
        accepted[:, cols] = torch.where(ok, step, accepted[:, cols])
        f_new[:, cols] = torch.where(ok, f_ref + change, f_new[:, cols])
        pending &= ~ok
        step = torch.where(pending, step * 0.5, step)
    return accepted, f_new, dz


@dataclass
class _State:
    """The solver's per-column state of one layer chunk (every tensor has a columns axis K)."""

    p: torch.Tensor  # (L, K, H + 1) parameters, the bias last
    z: torch.Tensor  # (L, n, K) logits
    sig: torch.Tensor  # (L, n, K) sigmoid(z)
    f: torch.Tensor  # (L, K) objective
    g: torch.Tensor  # (L, K, H + 1) gradient
    gamma: torch.Tensor  # (L, K) initial inverse-Hessian scale
    active: torch.Tensor  # (L, K) bool: still iterating
    iterations: torch.Tensor  # (L, K) long
    hist: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]  # (s, y, rho) pairs, oldest first

    def select(self, keep: torch.Tensor) -> _State:
        """The state of the columns ``keep`` (an index tensor) only."""
        hist = [
            (s.index_select(1, keep), y.index_select(1, keep), r.index_select(1, keep))
            for s, y, r in self.hist
        ]
        return _State(
            p=self.p.index_select(1, keep),
            z=self.z.index_select(2, keep),
            sig=self.sig.index_select(2, keep),
            f=self.f.index_select(1, keep),
            g=self.g.index_select(1, keep),
            gamma=self.gamma.index_select(1, keep),
            active=self.active.index_select(1, keep),
            iterations=self.iterations.index_select(1, keep),
            hist=hist,
        )


def _compact(
    prob: _Problem, st: _State, cols: torch.Tensor, out: _State
) -> tuple[_Problem, _State, torch.Tensor]:
    """Record every working column's state in ``out`` (at its original index ``cols``), then drop the
    columns that stopped on every layer of the chunk, so that later iterations cost only what still runs."""
    out.p[:, cols], out.f[:, cols], out.g[:, cols] = st.p, st.f, st.g
    out.iterations[:, cols], out.active[:, cols] = st.iterations, st.active
    keep = torch.nonzero(st.active.any(0)).flatten()
    return prob.select(keep), st.select(keep), cols[keep]


def _solve_chunk(prob: _Problem, p: torch.Tensor, tol: float, max_iter: int, history: int):
    """Run L-BFGS on one layer chunk from ``p``; returns (p, iterations, loss, grad max, converged).

    Every tenth iteration, when under 3/4 of the columns still run on some layer, the stopped ones leave the
    working set (the columns' problems are independent: each follows the same path, up to float round-off).
    """
    z = prob.logits(p)
    f = prob.data_loss(z) + prob.penalty(p)
    g, sig = prob.gradient(z, p)
    active = g.abs().amax(-1) > tol
    st = _State(p, z, sig, f, g, torch.ones_like(f), active, torch.zeros_like(f, dtype=torch.long), [])
    out = _State(p.clone(), z, sig, f.clone(), g.clone(), st.gamma, active.clone(), st.iterations.clone(), [])
    cols = torch.arange(p.shape[1], device=p.device)
    for it in range(max_iter):
        if it % 10 == 0 and it > 0 and int(st.active.any(0).sum()) < 0.75 * len(cols):
            prob, st, cols = _compact(prob, st, cols, out)
        if not bool(st.active.any()):
            break
        _iterate(prob, st, tol, history, first=it == 0, recompute=it % 10 == 9)
    _compact(prob, st, cols, out)
    gmax = out.g.abs().amax(-1)
    return out.p, out.iterations, out.f, gmax, gmax <= tol


def _iterate(prob: _Problem, st: _State, tol: float, history: int, first: bool, recompute: bool) -> None:
    """One L-BFGS iteration of every active column, in place."""
    g, active = st.g, st.active
    d = _direction(g, st.hist, st.gamma)
    gd = _dot(g, d)
    bad = gd >= 0  # not a descent direction (numerical trouble): fall back to the gradient
    if bool(bad.any()):
        d = torch.where(bad[..., None], -g, d)
        gd = _dot(g, d)
    d.mul_(active[..., None])
    gd = torch.where(active, gd, torch.zeros_like(gd))
    step = torch.ones_like(st.f)
    if first:
        step = torch.clamp(1.0 / g.abs().sum(-1).clamp_min(1e-12), max=1.0)
    step, f_new, dz = _line_search(prob, st.p, d, st.z, st.sig, st.f, gd, step)
    active &= ~(active & (step == 0))  # no acceptable step: stuck
    s = d * step[..., None]
    st.p = st.p + s
    if recompute:  # against drift of the updated logits
        st.z = prob.logits(st.p)
        st.f = prob.data_loss(st.z) + prob.penalty(st.p)
    else:
        st.z.addcmul_(step[:, None], dz)
        st.f = f_new
    g_new, st.sig = prob.gradient(st.z, st.p)
    yv = g_new - g
    sy = _dot(s, yv)
    curved = sy > 1e-10
    rho = torch.where(curved, 1.0 / torch.where(curved, sy, torch.ones_like(sy)), torch.zeros_like(sy))
    st.gamma = torch.where(curved, sy / _dot(yv, yv).clamp_min(1e-20), st.gamma)
    st.hist.append((s, yv, rho))
    if len(st.hist) > history:
        st.hist.pop(0)
    st.iterations += active.long()
    st.g = g_new
    active &= g_new.abs().amax(-1) > tol


def fit_logistic(
    x: torch.Tensor,
    y: torch.Tensor,
    l2: torch.Tensor,
    *,
    weight: torch.Tensor | None = None,
    tol: float = 1e-4,
    max_iter: int = 500,
    history: int = 10,
    memory_mb: float = 1024,
    init: tuple[torch.Tensor, torch.Tensor] | None = None,
    penalized: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, Convergence]:
    """Fit every column of ``y`` on every layer of ``x``; return (weight (L, H, K), bias (L, K), convergence).

    ``x`` float32 (layers, rows, hidden); ``y`` float (rows, columns) in {0, 1}; ``l2`` (layers, columns) the
    penalty per problem; ``weight`` optional (rows, columns) row weights (0 leaves a row out of a column's
    problem; ``n`` counts the rows with a weight). Starts at ``init`` (weight (L, H, K), bias (L, K)), e.g. the
    solution for a stronger penalty, else at w = 0, b = the weighted log-odds. ``penalized`` optional (hidden,)
    0/1: the L2 term covers only the features marked 1 (conditional probing leaves its baseline one-hot
    block free). On a CPU the layers are solved
    one at a time, so that the columns that stopped leave the working set per layer; on an accelerator in
    chunks of layers that fit ``memory_mb``.
    """
    num_layers, n, hidden = x.shape
    k = y.shape[1]
    y = y.to(x.device, torch.float32)
    counts = (
        (weight > 0).sum(0).float() if weight is not None else torch.full((k,), float(n), device=x.device)
    )
    inv_n = 1.0 / counts.clamp_min(1.0)
    total = counts if weight is None else weight.sum(0)
    per_layer = 4 * (6 * n * max(k, 1) + (2 * history + 8) * max(k, 1) * (hidden + 1))
    chunk = 1 if x.device.type == "cpu" else max(1, min(num_layers, int(memory_mb * 2**20 // per_layer)))
    weights = torch.empty((num_layers, hidden, k))
    biases = torch.empty((num_layers, k))
    out = {name: np.empty((num_layers, k)) for name in ("iterations", "loss", "grad_norm", "converged")}
    mask = None if penalized is None else penalized.to(x.device, torch.float32)

    def solve(part: slice) -> None:
        """Fit the layers ``part`` and store their results (each call writes its own rows only)."""
        with torch.no_grad():  # (grad mode is per thread)
            xs = x[part]
            if weight is None:
                center = xs.mean(1, keepdim=True)  # (L, 1, H)
            else:
                center = torch.einsum("nk,lnh->lkh", weight, xs) / total.clamp_min(1e-12)[None, :, None]
            prob = _Problem(xs, y, weight, inv_n, l2[part].to(x.device, torch.float32), center, mask)
            p = torch.zeros((part.stop - part.start, k, hidden + 1), device=x.device)
            if init is None:
                p[:, :, -1] = cold_bias(y, weight)
            else:
                p[:, :, :-1] = init[0][part].transpose(1, 2).to(x.device)
                p[:, :, -1] = init[1][part].to(x.device) + _dot(center, p[:, :, :-1])
            p, iters, f, gmax, done = _solve_chunk(prob, p, tol, max_iter, history)
            weights[part] = p[:, :, :-1].transpose(1, 2).cpu()
            biases[part] = (p[:, :, -1] - _dot(center, p[:, :, :-1])).cpu()
            for name, v in zip(out, (iters, f, gmax, done), strict=True):
                out[name][part] = v.cpu().numpy()

    _for_each_part(
        [slice(s, min(num_layers, s + chunk)) for s in range(0, num_layers, chunk)], solve, x.device
    )
    conv = Convergence(
        iterations=out["iterations"].astype(np.int64),
        loss=out["loss"],
        grad_norm=out["grad_norm"],
        converged=out["converged"].astype(bool),
        tol=tol,
        max_iter=max_iter,
    )
    return weights, biases, conv


def _for_each_part(parts: list[slice], solve: Callable[[slice], None], device: torch.device) -> None:
    """Run ``solve`` on every layer part. On a CPU with several torch threads the parts run side by side, one
    thread each: a layer's problems are too small for torch to split one operation well across threads, and
    the solver's Python steps of one layer overlap the other layers' arithmetic (torch releases the GIL)."""
    threads = torch.get_num_threads()
    if device.type != "cpu" or threads < 2 or len(parts) < 2:
        for part in parts:
            solve(part)
        return
    torch.set_num_threads(1)
    try:
        with ThreadPoolExecutor(min(threads, len(parts))) as pool:
            list(pool.map(solve, parts))  # (list: a part's exception is raised here)
    finally:
        torch.set_num_threads(threads)


def cold_bias(y: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """(columns,) the solver's cold start's bias (with weights 0): each column's weighted log-odds of ``y``
    (rows, columns), clamped to frequencies 1e-4 ... 1 - 1e-4."""
    y = y.to(torch.float32)
    wy = y if weight is None else y * weight
    total = torch.tensor(float(len(y))) if weight is None else weight.sum(0)
    return torch.logit((wy.sum(0) / total.clamp_min(1e-12)).clamp(1e-4, 1 - 1e-4))


def l2_of_c(c: np.ndarray | float, rows: np.ndarray | float) -> np.ndarray:
    """Our penalty ``l2`` for scikit-learn's inverse strength ``C`` on ``rows`` training rows: 1 / (C n)."""
    return 1.0 / (np.asarray(c, np.float64) * np.maximum(np.asarray(rows, np.float64), 1.0))
