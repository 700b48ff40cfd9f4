"""The similarity measurement's kernels of the DA-HGNN network: the affinity MLP over the robot-candidate pairs
(:func:`pair_mlp`) and the log-domain Sinkhorn iterations (:func:`sinkhorn`) that turn the affinity into
the correspondence matrix S.

Each is an autograd function: on the CPU fused numba kernels (the batch rows split among threads,
:mod:`areasearch.models.kernels`; the pairs that are not allowed, and Sinkhorn's rows and columns that
are off, cost nothing), elsewhere the same computation in plain torch ops (:func:`pair_mlp_reference`,
:func:`sinkhorn_reference`, also the tests' references).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numba
import numpy as np
import torch
from torch import Tensor

from .kernels import as_numpy, fixed_numpy, gather_pairs, hidden_grad, pair_logit, row_ranges, run_jobs, run_ranges

# ---------------------------------------------------------------------------------------------- MLP scores


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _pair_mlp_forward_kernel(edge, rows, p_part, q_part, w, bias, out, start, stop):  # type: ignore[no-untyped-def]
    """Batch rows [start, stop) of :func:`pair_mlp`."""
    n_p, n_q, a_dim = rows.shape[1], rows.shape[2], edge.shape[1]
    heads = w.shape[0]
    z = np.empty(a_dim, dtype=np.float32)
    for b in range(start, stop):
        for p in range(n_p):
            for q in range(n_q):
                r = rows[b, p, q]
                if r < 0:
                    for m in range(heads):
                        out[b, p, q, m] = 0.0
                    continue
                # written out: as an inlined helper this loop compiles to other machine code
                for i in range(a_dim):
                    z[i] = max(edge[r, i] + p_part[b, p, i] + q_part[b, q, i], np.float32(0.0))
                for m in range(heads):
                    logit = pair_logit(w, bias, z, m, a_dim)
                    out[b, p, q, m] = logit


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _pair_mlp_backward_kernel(  # type: ignore[no-untyped-def]
    edge, rows, p_part, q_part, w, bias, grad, g_edge, g_ppart, g_qpart, g_w, g_bias, start, stop
):
    """Gradients of :func:`_pair_mlp_forward_kernel` for batch rows [start, stop) (g_edge: the rows
    of their pairs); g_w and g_bias are this thread's own accumulators."""
    n_p, n_q, a_dim = rows.shape[1], rows.shape[2], edge.shape[1]
    heads = w.shape[0]
    z = np.empty(a_dim, dtype=np.float32)
    dz = np.empty(a_dim, dtype=np.float32)
    acc_w, acc_bias = np.zeros_like(g_w), np.zeros_like(g_bias)  # kept off shared cache lines
    for b in range(start, stop):
        g_ppart[b] = 0.0
        g_qpart[b] = 0.0
        for p in range(n_p):
            for q in range(n_q):
                r = rows[b, p, q]
                if r < 0:
                    continue
                for i in range(a_dim):
                    z[i] = max(edge[r, i] + p_part[b, p, i] + q_part[b, q, i], np.float32(0.0))
                    dz[i] = 0.0
                for m in range(heads):
                    gl = grad[b, p, q, m]
                    acc_bias[m] += gl
                    for i in range(a_dim):
                        acc_w[m, i] += gl * z[i]
                        dz[i] += gl * w[m, i]
                hidden_grad(dz, z, r, b, p, q, g_edge, g_ppart, g_qpart, a_dim)
    g_w[:] = acc_w
    g_bias[:] = acc_bias


def _pair_mlp_forward(*inputs: Tensor) -> tuple[list[Tensor], Tensor]:
    edge, rows, p_part, q_part, weight, bias = inputs
    b, n_p, n_q = rows.shape
    args = [t.detach().contiguous() for t in (edge, p_part, q_part, weight, bias)]
    out = edge.new_empty(b, n_p, n_q, weight.shape[0])
    saved = [args[0], rows, *args[1:]]
    arrays = [as_numpy(t) if t.dtype.is_floating_point else fixed_numpy(t) for t in saved]
    run_ranges(_pair_mlp_forward_kernel, row_ranges(b * n_p * n_q // 4, 1, b), *arrays, out.numpy())
    return saved, out


class _PairMLP(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, *inputs: Tensor) -> Tensor:  # type: ignore[override]
        saved, out = _pair_mlp_forward(*inputs)
        ctx.save_for_backward(*saved)
        return out

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, ...]:  # type: ignore[override]
        edge, rows, p_part, q_part, weight, bias = ctx.saved_tensors
        b, n_p, n_q = rows.shape
        ranges = row_ranges(b * n_p * n_q // 4, 1, b)
        g_edge = torch.zeros_like(edge)  # rows of pairs that are not allowed (if any) get 0
        g_pp, g_qp = torch.empty_like(p_part), torch.empty_like(q_part)
        acc = [t.new_zeros(len(ranges), *t.shape) for t in (weight, bias)]
        fixed = [as_numpy(t) if t.dtype.is_floating_point else fixed_numpy(t) for t in ctx.saved_tensors]
        common = (*fixed, grad.contiguous().numpy(), g_edge.numpy(), g_pp.numpy(), g_qp.numpy())
        kernel: Any = _pair_mlp_backward_kernel
        parts = [[t[i].numpy() for t in acc] for i in range(len(ranges))]
        jobs = [functools.partial(kernel, *common, *part, lo, hi) for part, (lo, hi) in zip(parts, ranges, strict=True)]
        run_jobs(jobs)
        return g_edge, None, g_pp, g_qp, acc[0].sum(0), acc[1].sum(0)


def pair_mlp(edge: Tensor, rows: Tensor, p_part: Tensor, q_part: Tensor, weight: Tensor, bias: Tensor) -> Tensor:
    """An MLP of one hidden layer over the pairs of two node sets: out[b, p, q] = weight relu(edge[row]
    + p_part[b, p] + q_part[b, q]) + bias on the allowed pairs, 0 on the others (which cost nothing).
    ``rows`` (B, P, Q) int64 and ``edge`` (N, A) are a pair table as in
    :func:`~areasearch.models.cross_attention.cross_attention`;
    p_part (B, P, A), q_part (B, Q, A), weight (M, A), bias (M,); returns (B, P, Q, M). The affinity
    MLP of the similarity measurement. On the CPU, fused numba kernels; elsewhere
    :func:`pair_mlp_reference`."""
    inputs = (edge, rows, p_part, q_part, weight, bias)
    if edge.device.type != "cpu" or edge.dtype != torch.float32:
        return pair_mlp_reference(*inputs)
    if not torch.is_grad_enabled() or not any(t.requires_grad for t in (edge, p_part, q_part, weight, bias)):
        return _pair_mlp_forward(*inputs)[1]
    return _PairMLP.apply(*inputs)  # type: ignore[no-any-return]


def pair_mlp_reference(
    edge: Tensor, rows: Tensor, p_part: Tensor, q_part: Tensor, weight: Tensor, bias: Tensor
) -> Tensor:
    """:func:`pair_mlp` in plain torch ops."""
    z = torch.relu(gather_pairs(edge, rows) + p_part[:, :, None] + q_part[:, None])  # (B, P, Q, A)
    return (z @ weight.t() + bias) * (rows >= 0)[..., None]


# ---------------------------------------------------------------------------------------------- log-domain Sinkhorn

SINKHORN_OFF = -1e4
"""Potential of a row or column that is off (padded, or a slack with nothing to absorb)."""


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _on(mask, b, out):  # type: ignore[no-untyped-def]
    """Indices i where mask[b, i], into ``out``; returns how many."""
    n = 0
    for i in range(mask.shape[1]):
        if mask[b, i]:
            out[n] = i
            n += 1
    return n


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _sinkhorn_forward_kernel(z, log_mu, log_nu, rows_on, cols_on, off, out, us, vs, start, stop):  # type: ignore[no-untyped-def]
    """Batch rows [start, stop) of :func:`sinkhorn`; us (B, T, R), vs (B, T, C) keep each
    iteration's potentials for the backward pass. Rows and columns that are off get potential
    ``off`` and are skipped (their terms are exp(about -1e4) = 0 in float32)."""
    nr, nc = z.shape[1], z.shape[2]
    iters = us.shape[1]
    ri = np.empty(nr, dtype=np.int64)
    ci = np.empty(nc, dtype=np.int64)
    u = np.empty(nr, dtype=np.float32)
    v = np.empty(nc, dtype=np.float32)
    for b in range(start, stop):
        n_r, n_c = _on(rows_on, b, ri), _on(cols_on, b, ci)
        u[:] = off
        v[:] = off
        for t in range(iters):
            for a in range(n_r):
                i = ri[a]
                top = np.float32(-np.inf)
                for k in range(n_c):
                    j = ci[k]
                    top = max(top, z[b, i, j] + (v[j] if t > 0 else np.float32(0.0)))
                acc = np.float32(0.0)
                for k in range(n_c):
                    j = ci[k]
                    acc += math.exp(z[b, i, j] + (v[j] if t > 0 else np.float32(0.0)) - top)
                u[i] = log_mu[b, i] - (top + math.log(acc))
            for k in range(n_c):
                j = ci[k]
                top = np.float32(-np.inf)
                for a in range(n_r):
                    i = ri[a]
                    top = max(top, z[b, i, j] + u[i])
                acc = np.float32(0.0)
                for a in range(n_r):
                    i = ri[a]
                    acc += math.exp(z[b, i, j] + u[i] - top)
                v[j] = log_nu[b, j] - (top + math.log(acc))
            us[b, t] = u
            vs[b, t] = v
        for i in range(nr):
            for j in range(nc):
                out[b, i, j] = z[b, i, j] + u[i] + v[j]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _sinkhorn_backward_kernel(z, log_mu, log_nu, rows_on, cols_on, us, vs, grad, g_z, start, stop):  # type: ignore[no-untyped-def]
    """Gradient of :func:`_sinkhorn_forward_kernel` w.r.t. z for batch rows [start, stop), back
    through the iterations (u_i = log_mu_i - LSE_j(z_ij + v_j), v_j = log_nu_j - LSE_i(z_ij + u_i))."""
    nr, nc = z.shape[1], z.shape[2]
    iters = us.shape[1]
    ri = np.empty(nr, dtype=np.int64)
    ci = np.empty(nc, dtype=np.int64)
    gu = np.empty(nr, dtype=np.float32)
    gv = np.empty(nc, dtype=np.float32)
    for b in range(start, stop):
        n_r, n_c = _on(rows_on, b, ri), _on(cols_on, b, ci)
        g_z[b] = grad[b]
        gu[:] = 0.0
        gv[:] = 0.0
        for a in range(n_r):
            i = ri[a]
            for j in range(nc):
                gu[i] += grad[b, i, j]
        for k in range(n_c):
            j = ci[k]
            for i in range(nr):
                gv[j] += grad[b, i, j]
        for t in range(iters - 1, -1, -1):
            for k in range(n_c):  # v^t_j = log_nu_j - LSE_i(z_ij + u^t_i)
                j = ci[k]
                g = gv[j]
                if g == 0:
                    continue
                lse = log_nu[b, j] - vs[b, t, j]
                for a in range(n_r):
                    i = ri[a]
                    d = g * math.exp(z[b, i, j] + us[b, t, i] - lse)
                    g_z[b, i, j] -= d
                    gu[i] -= d
            gv[:] = 0.0
            for a in range(n_r):  # u^t_i = log_mu_i - LSE_j(z_ij + v^(t-1)_j), v^(-1) = 0
                i = ri[a]
                g = gu[i]
                if g == 0:
                    continue
                lse = log_mu[b, i] - us[b, t, i]
                for k in range(n_c):
                    j = ci[k]
                    d = g * math.exp(z[b, i, j] + (vs[b, t - 1, j] if t > 0 else np.float32(0.0)) - lse)
                    g_z[b, i, j] -= d
                    gv[j] -= d
            gu[:] = 0.0


def _sinkhorn_forward(z: Tensor, log_mu: Tensor, log_nu: Tensor, rows_on: Tensor, cols_on: Tensor, iters: int):  # type: ignore[no-untyped-def]
    b, nr, nc = z.shape
    z = z.detach().contiguous()
    log_mu, log_nu = log_mu.detach().contiguous(), log_nu.detach().contiguous()
    out, us, vs = torch.empty_like(z), z.new_empty(b, iters, nr), z.new_empty(b, iters, nc)
    arrays = [t.numpy() for t in (z, log_mu, log_nu, rows_on.contiguous(), cols_on.contiguous())]
    run_ranges(
        _sinkhorn_forward_kernel,
        row_ranges(b * nr * nc // 4, 1, b),
        *arrays,
        np.float32(SINKHORN_OFF),
        out.numpy(),
        us.numpy(),
        vs.numpy(),
    )
    return (z, log_mu, log_nu, rows_on, cols_on, us, vs), out


class _Sinkhorn(torch.autograd.Function):
    @staticmethod
    def forward(
        ctx: Any, z: Tensor, log_mu: Tensor, log_nu: Tensor, rows_on: Tensor, cols_on: Tensor, iters: int
    ) -> Tensor:  # type: ignore[override]
        saved, out = _sinkhorn_forward(z, log_mu, log_nu, rows_on, cols_on, iters)
        ctx.save_for_backward(*saved)
        return out

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, ...]:  # type: ignore[override]
        z, log_mu, log_nu, rows_on, cols_on, us, vs = ctx.saved_tensors
        b, nr, nc = z.shape
        g_z = torch.empty_like(z)
        arrays = [t.numpy() for t in (z, log_mu, log_nu, rows_on.contiguous(), cols_on.contiguous(), us, vs)]
        run_ranges(
            _sinkhorn_backward_kernel,
            row_ranges(b * nr * nc // 4, 1, b),
            *arrays,
            grad.contiguous().numpy(),
            g_z.numpy(),
        )
        return g_z, None, None, None, None, None


def sinkhorn(z: Tensor, log_mu: Tensor, log_nu: Tensor, rows_on: Tensor, cols_on: Tensor, iters: int) -> Tensor:
    """``iters`` log-domain Sinkhorn iterations on the log-couplings z (B, R, C) towards the log
    marginals log_mu (B, R) and log_nu (B, C), rows first: u_i = log_mu_i - LSE_j(z_ij + v_j), then
    v_j = log_nu_j - LSE_i(z_ij + u_i), from v = 0. Rows and columns that are off (``rows_on`` (B, R),
    ``cols_on`` (B, C) False) get potential -1e4 from the start (they take no part). Returns z + u + v
    (B, R, C); differentiable in z. On the CPU, fused numba kernels (a padded batch's off rows and
    columns cost nothing); elsewhere :func:`sinkhorn_reference`."""
    if z.device.type != "cpu" or z.dtype != torch.float32:
        return sinkhorn_reference(z, log_mu, log_nu, rows_on, cols_on, iters)
    if not (torch.is_grad_enabled() and z.requires_grad):
        return _sinkhorn_forward(z, log_mu, log_nu, rows_on, cols_on, iters)[1]
    return _Sinkhorn.apply(z, log_mu, log_nu, rows_on, cols_on, iters)  # type: ignore[no-any-return]


def sinkhorn_reference(
    z: Tensor, log_mu: Tensor, log_nu: Tensor, rows_on: Tensor, cols_on: Tensor, iters: int
) -> Tensor:
    """:func:`sinkhorn` in plain torch ops."""
    off = z.new_tensor(SINKHORN_OFF)
    zt = z.transpose(1, 2).contiguous()
    u = torch.zeros_like(log_mu)
    v = torch.where(cols_on, 0.0, off)  # a column that is off takes no part, from the first iteration
    for _ in range(iters):
        u = torch.where(rows_on, log_mu - torch.logsumexp(z + v[:, None, :], dim=2), off)
        v = torch.where(cols_on, log_nu - torch.logsumexp(zt + u[:, None, :], dim=2), off)
    return z + u[:, :, None] + v[:, None, :]
