"""MLP attention, the cross-graphs' kernel of the DA-HGNN network (eq. 9 of the paper): between two node sets,
both ways, on the allowed pairs of a pair table (:func:`~areasearch.models.kernels.pair_rows`).

:func:`cross_attention` is an autograd function: on the CPU fused numba kernels (the batch rows split
among threads, :mod:`areasearch.models.kernels`), elsewhere the same computation in plain torch ops
(:func:`cross_attention_reference`, also the tests' reference). Its docstring has the shapes.
"""

from __future__ import annotations

import functools
from typing import Any

import numba
import numpy as np
import torch
from torch import Tensor

from .kernels import as_numpy, fixed_numpy, gather_pairs, hidden_grad, pair_logit, row_ranges, run_jobs, run_ranges


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _cross_forward_kernel(  # type: ignore[no-untyped-def]
    edge, rows, p_part, q_part, w, bias, kind, vq, vp, cap, out_p, den_p, out_q, den_q, e_all, t_all, start, stop
):
    """Batch rows [start, stop) of :func:`cross_attention` (its docstring has the shapes). Per allowed
    pair, in one pass: its weight (e_all, and tanh(l / cap) in t_all, kept for the backward pass;
    tanh(y) = 1 - 2 / (exp(2 y) + 1)) and its terms of the weighted sums; then the normalisation.
    The weights of pairs that are not allowed are left unset (never read)."""
    n_p, n_q, a_dim = rows.shape[1], rows.shape[2], edge.shape[1]
    heads, dv = vq.shape[2], vq.shape[3]
    slots = out_p.shape[2]
    with_q = out_q.shape[0] > 0
    inv_cap = np.float32(1.0) / cap
    z = np.empty(a_dim, dtype=np.float32)
    for b in range(start, stop):
        out_p[b] = 0.0
        den_p[b] = 0.0
        if with_q:
            out_q[b] = 0.0
            den_q[b] = 0.0
        for p in range(n_p):
            for q in range(n_q):
                r = rows[b, p, q]
                if r < 0:
                    continue
                # written out: as an inlined helper this loop compiles to other machine code
                for i in range(a_dim):
                    z[i] = max(edge[r, i] + p_part[b, p, i] + q_part[b, q, i], np.float32(0.0))
                for m in range(heads):
                    logit = pair_logit(w, bias, z, m, a_dim)
                    y = min(max(logit * inv_cap, np.float32(-20.0)), np.float32(20.0))
                    t = np.float32(1.0) - np.float32(2.0) / (np.exp(np.float32(2.0) * y) + np.float32(1.0))
                    t_all[b, p, q, m] = t
                    e_all[b, p, q, m] = np.exp(cap * t)
                kq = kind[b, q]
                for m in range(heads):
                    e = e_all[b, p, q, m]
                    den_p[b, p, 0, m] += e
                    for d in range(dv):
                        out_p[b, p, 0, m, d] += e * vq[b, q, m, d]
                    if kq >= 0 and slots > 1:
                        den_p[b, p, 1 + kq, m] += e
                        for d in range(dv):
                            out_p[b, p, 1 + kq, m, d] += e * vq[b, q, m, d]
                    if with_q:
                        den_q[b, q, m] += e
                        for d in range(dv):
                            out_q[b, q, m, d] += e * vp[b, p, m, d]
        for p in range(n_p):
            for s in range(slots):
                for m in range(heads):
                    if den_p[b, p, s, m] > 0:
                        inv = np.float32(1.0) / den_p[b, p, s, m]
                        for d in range(dv):
                            out_p[b, p, s, m, d] *= inv
        if with_q:
            for q in range(n_q):
                for m in range(heads):
                    if den_q[b, q, m] > 0:
                        inv = np.float32(1.0) / den_q[b, q, m]
                        for d in range(dv):
                            out_q[b, q, m, d] *= inv


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _cross_backward_kernel(  # type: ignore[no-untyped-def]
    edge, rows, p_part, q_part, w, bias, kind, vq, vp, cap, out_p, den_p, out_q, den_q, e_all, t_all,
    g_p, g_q, g_edge, g_ppart, g_qpart, g_w, g_bias, g_vq, g_vp, start, stop,
):  # fmt: skip
    """Gradients of :func:`_cross_forward_kernel` for batch rows [start, stop) (g_edge: the rows of
    their pairs); g_w and g_bias are this thread's own accumulators."""
    n_p, n_q, a_dim = rows.shape[1], rows.shape[2], edge.shape[1]
    heads, dv = vq.shape[2], vq.shape[3]
    slots = out_p.shape[2]
    with_q = out_q.shape[0] > 0
    z = np.empty(a_dim, dtype=np.float32)
    dz = np.empty(a_dim, dtype=np.float32)
    acc_w = np.zeros_like(g_w)  # this thread's sums, written out at the end: threads that
    acc_bias = np.zeros_like(g_bias)  # add into neighbouring memory would fight over cache lines
    for b in range(start, stop):
        g_ppart[b] = 0.0
        g_qpart[b] = 0.0
        g_vq[b] = 0.0
        if with_q:
            g_vp[b] = 0.0
        for p in range(n_p):
            for q in range(n_q):
                r = rows[b, p, q]
                if r < 0:
                    continue
                for i in range(a_dim):
                    z[i] = max(edge[r, i] + p_part[b, p, i] + q_part[b, q, i], np.float32(0.0))
                    dz[i] = 0.0
                kq = kind[b, q]
                for m in range(heads):
                    e = e_all[b, p, q, m]
                    t = t_all[b, p, q, m]
                    de = np.float32(0.0)
                    for s in range(slots):
                        if s > 0 and s != 1 + kq:
                            continue
                        inv = np.float32(1.0) / den_p[b, p, s, m]
                        acc = np.float32(0.0)
                        for d in range(dv):
                            gp = g_p[b, p, s, m, d]
                            acc += gp * (vq[b, q, m, d] - out_p[b, p, s, m, d])
                            g_vq[b, q, m, d] += e * inv * gp
                        de += acc * inv
                    if with_q:
                        inv = np.float32(1.0) / den_q[b, q, m]
                        acc = np.float32(0.0)
                        for d in range(dv):
                            gq = g_q[b, q, m, d]
                            acc += gq * (vp[b, p, m, d] - out_q[b, q, m, d])
                            g_vp[b, p, m, d] += e * inv * gq
                        de += acc * inv
                    dl = de * e * (np.float32(1.0) - t * t)
                    acc_bias[m] += dl
                    for i in range(a_dim):
                        acc_w[m, i] += dl * z[i]
                        dz[i] += dl * w[m, i]
                hidden_grad(dz, z, r, b, p, q, g_edge, g_ppart, g_qpart, a_dim)
    g_w[:] = acc_w
    g_bias[:] = acc_bias


def _cross_forward(
    edge: Tensor,
    rows: Tensor,
    p_part: Tensor,
    q_part: Tensor,
    weight: Tensor,
    bias: Tensor,
    kind: Tensor,
    vq: Tensor,
    vp: Tensor | None,
    kinds: int,
    cap: float,
) -> tuple[list[Tensor], list[Tensor]]:
    """The forward kernel: (its inputs as contiguous tensors, [out_p, den_p, out_q, den_q, e, t])."""
    b, n_p, n_q = rows.shape
    heads = weight.shape[0]
    args = [t.detach().contiguous() for t in (edge, p_part, q_part, weight, bias)]
    vq_ = vq.detach().contiguous().view(b, n_q, heads, -1)
    vp_ = vp.detach().contiguous().view(b, n_p, heads, -1) if vp is not None else vq_.new_empty(0, 0, heads, 1)
    dv = vq_.shape[3]
    slots = 1 + kinds if kinds > 1 else 1
    outs = [
        vq_.new_empty(b, n_p, slots, heads, dv),
        vq_.new_empty(b, n_p, slots, heads),
        vq_.new_empty(b if vp is not None else 0, n_q, heads, dv),
        vq_.new_empty(b if vp is not None else 0, n_q, heads),
        vq_.new_empty(b, n_p, n_q, heads),  # the weights e
        vq_.new_empty(b, n_p, n_q, heads),  # tanh(logit / cap)
    ]
    inputs = [args[0], rows, *args[1:], kind, vq_, vp_]
    arrays = [as_numpy(t) if t.dtype.is_floating_point else fixed_numpy(t) for t in inputs]
    run_ranges(
        _cross_forward_kernel,
        row_ranges(b * n_p * n_q // 4, 1, b),
        *arrays,
        np.float32(cap),
        *(t.numpy() for t in outs),
    )
    return inputs, outs


class _CrossAttention(torch.autograd.Function):
    @staticmethod
    def forward(  # type: ignore[override]
        ctx: Any,
        edge: Tensor,
        rows: Tensor,
        p_part: Tensor,
        q_part: Tensor,
        weight: Tensor,
        bias: Tensor,
        kind: Tensor,
        vq: Tensor,
        vp: Tensor | None,
        kinds: int,
        cap: float,
    ) -> tuple[Tensor, Tensor]:
        inputs, outs = _cross_forward(edge, rows, p_part, q_part, weight, bias, kind, vq, vp, kinds, cap)
        ctx.save_for_backward(*inputs, *outs)
        ctx.cap, ctx.with_q = cap, vp is not None
        return outs[0], outs[2]

    @staticmethod
    def backward(ctx: Any, g_p: Tensor, g_q: Tensor) -> tuple[Tensor | None, ...]:  # type: ignore[override]
        edge, rows, p_part, q_part, weight, bias, _kind, vq, vp = ctx.saved_tensors[:9]
        out_p, den_p, out_q, den_q, e, t = ctx.saved_tensors[9:]
        b, n_p, n_q = rows.shape
        g_p = g_p.contiguous() if g_p is not None else torch.zeros_like(out_p)
        g_q = g_q.contiguous() if g_q is not None and ctx.with_q else torch.zeros_like(out_q)
        ranges = row_ranges(b * n_p * n_q // 4, 1, b)
        g_edge = torch.zeros_like(edge)  # rows of pairs that are not allowed (if any) get 0
        g_pp, g_qp = torch.empty_like(p_part), torch.empty_like(q_part)
        g_vq, g_vp = torch.empty_like(vq), torch.empty_like(vp)
        g_w = weight.new_zeros(len(ranges), *weight.shape)
        g_b = bias.new_zeros(len(ranges), *bias.shape)
        fixed = [as_numpy(x) if x.dtype.is_floating_point else fixed_numpy(x) for x in ctx.saved_tensors[:9]]
        saved = [x.numpy() for x in (out_p, den_p, out_q, den_q, e, t, g_p, g_q, g_edge, g_pp, g_qp)]
        kernel: Any = _cross_backward_kernel
        common = (*fixed, np.float32(ctx.cap), *saved)
        run_jobs(
            [
                functools.partial(kernel, *common, g_w[i].numpy(), g_b[i].numpy(), g_vq.numpy(), g_vp.numpy(), lo, hi)
                for i, (lo, hi) in enumerate(ranges)
            ]
        )
        g_vp_out = g_vp.flatten(2) if ctx.with_q else None
        return g_edge, None, g_pp, g_qp, g_w.sum(0), g_b.sum(0), None, g_vq.flatten(2), g_vp_out, None, None


def cross_attention(
    edge: Tensor,
    rows: Tensor,
    p_part: Tensor,
    q_part: Tensor,
    weight: Tensor,
    bias: Tensor,
    kind: Tensor,
    vq: Tensor,
    vp: Tensor | None,
    kinds: int,
    cap: float,
) -> tuple[Tensor, Tensor | None]:
    """MLP attention (eq. 9) between the P and the Q nodes of each batch row, both ways.

    The allowed pairs (p, q) are the rows of a pair table: ``rows`` (B, P, Q) int64 gives a pair's row,
    -1 for a pair that is not allowed (:func:`~areasearch.models.kernels.pair_rows`), and ``edge``
    (N, A) holds each row's edge term (the pair's projected edge features): only allowed pairs cost
    anything. Score of pair (p, q), head m: e = exp(cap * tanh(l / cap)), l = weight[m] . relu(edge[row]
    + p_part[p] + q_part[q]) + bias[m]. Returns ``out_p`` (B, P, S, M, dv / M): for each P node the
    e-weighted mean of the Q nodes' values ``vq`` (B, Q, dv) (head m reading the m-th slice), over all
    its Q nodes (slot 0) and, with ``kinds`` > 1, over those of each kind (slots 1 + kind[q]; ``kind``
    (B, Q) int64, -1 in none); and ``out_q`` (B, Q, M, dv / M), each Q node's weighted mean of the P
    nodes' values ``vp`` (B, P, dv), or None without ``vp``. A node with no allowed pair (in a slot)
    gets 0. p_part (B, P, A), q_part (B, Q, A), weight (M, A), bias (M,). On the CPU, fused numba
    kernels (the B rows split among threads); elsewhere :func:`cross_attention_reference`."""
    args = (edge, rows, p_part, q_part, weight, bias, kind, vq, vp, kinds, cap)
    if edge.device.type != "cpu" or edge.dtype != torch.float32:
        return cross_attention_reference(*args)
    if not torch.is_grad_enabled() or not any(
        t is not None and t.requires_grad for t in (edge, p_part, q_part, weight, bias, vq, vp)
    ):
        _, outs = _cross_forward(*args)
        return outs[0], (outs[2] if vp is not None else None)
    out_p, out_q = _CrossAttention.apply(*args)
    return out_p, (out_q if vp is not None else None)


def cross_attention_reference(
    edge: Tensor,
    rows: Tensor,
    p_part: Tensor,
    q_part: Tensor,
    weight: Tensor,
    bias: Tensor,
    kind: Tensor,
    vq: Tensor,
    vp: Tensor | None,
    kinds: int,
    cap: float,
) -> tuple[Tensor, Tensor | None]:
    """:func:`cross_attention` in plain torch ops."""
    b, n_p, n_q = rows.shape
    heads = weight.shape[0]
    allowed = rows >= 0
    z = torch.relu(gather_pairs(edge, rows) + p_part[:, :, None] + q_part[:, None])  # (B, P, Q, A)
    logits = z @ weight.t() + bias  # (B, P, Q, M)
    e = torch.exp(cap * torch.tanh(logits / cap)) * allowed[..., None]
    masks = [torch.ones_like(kind, dtype=e.dtype)]
    if kinds > 1:
        masks += [(kind == i).to(e.dtype) for i in range(kinds)]
    v = vq.view(b, n_q, heads, -1)
    outs = []
    for mask in masks:
        em = e * mask[:, None, :, None]  # (B, P, Q, M)
        num = torch.einsum("bpqm,bqmd->bpmd", em, v)
        den = em.sum(2)[..., None]
        outs.append(torch.where(den > 0, num / den.clamp(min=1e-30), torch.zeros_like(num)))
    out_q = None
    if vp is not None:
        num = torch.einsum("bpqm,bpmd->bqmd", e, vp.view(b, n_p, heads, -1))
        den = e.sum(1)[..., None]
        out_q = torch.where(den > 0, num / den.clamp(min=1e-30), torch.zeros_like(num))
    return torch.stack(outs, dim=2), out_q
