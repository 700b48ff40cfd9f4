"""The fused CPU kernels of :mod:`areasearch.models.dahgnn`, its costliest parts, each an autograd function
with a plain-torch reference (used on other devices and by the tests):

* :func:`sparse_attention`: multi-head attention over neighbour lists (the self-graphs);
* :func:`cross_attention`: MLP attention between two node sets, both ways (the cross-graphs);
* :func:`pair_mlp`: an MLP over the pairs of two node sets (the affinity of the similarity measure);
* :func:`sinkhorn`: log-domain Sinkhorn iterations.

The pair kernels read the allowed pairs' edge terms from a pair table (one row per allowed pair,
:func:`pair_rows`) and skip the other pairs, and Sinkhorn skips rows and columns that are off, so
the padding of a batch of decisions of different sizes costs (almost) nothing. Per-thread sums of
shared gradients stay in thread-local arrays (threads adding into neighbouring memory would fight
over cache lines).

**Sparse attention.** Each query row attends, per head, to the source rows its neighbour list names: logits q . k, a
softmax over the listed neighbours, the weighted sum of their values (eqs. 6-8 of the paper, on a
sparse graph). :func:`sparse_attention` is an autograd function. On the CPU its forward and backward
passes are fused numba kernels (no K-fold copies of keys or values, the softmax inside the loop), run
on up to ``torch.get_num_threads()`` threads over disjoint groups of rows; elsewhere (CUDA) it is
the same computation in plain torch ops (:func:`sparse_attention_reference`, also the tests'
reference).

Shapes: P query rows, S source rows, G graphs, H heads (H / G per graph, graph g owning heads
g * H / G ...), K neighbours per graph, dk key width, dv value width per head. ``idx`` (P, G, K)
int64 holds each graph's neighbour rows, -1 for "no neighbour"; a query with no neighbour in a
graph gets 0 from it. Queries are expected pre-scaled (1 / sqrt(dk)). Keys (S, Hk, dk)
and values (S, Hv, dv) may have fewer heads than the queries: head h reads key head h % Hk and value
head h % Hv (graphs that share a node set's keys or values, each with its own queries and lists).

Threads: the scatter of the backward pass into the sources' gradients is race-free when the rows
are cut into groups whose neighbours lie in disjoint source ranges; ``groups`` says where such
groups may be cut (one decision of a batch: its neighbours are its own): an int, every that many
rows, or the sorted row offsets of the groups' starts.
"""

from __future__ import annotations

import bisect
import functools
import itertools
import math
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numba
import numpy as np
import torch
from torch import Tensor

_MIN_ROWS_PER_THREAD = 4096
"""Below this many query rows per thread the kernels run on the calling thread only."""

_pool: ThreadPoolExecutor | None = None
_CPUS = os.cpu_count() or 1


def _threads(work: int, groups: int | Sequence[int], rows: int | None = None) -> list[tuple[int, int]]:
    """Contiguous ranges of about equal size over ``rows`` (default ``work``) rows, cut at group
    boundaries, one per thread; one range when the ``work`` (rows of the sparse kernels) is small."""
    rows = work if rows is None else rows
    if work < 2 * _MIN_ROWS_PER_THREAD:
        return [(0, rows)]
    n = max(1, min(torch.get_num_threads(), work // _MIN_ROWS_PER_THREAD, _CPUS))
    if n == 1 or rows < 2:
        return [(0, rows)]
    if isinstance(groups, int):
        starts: Sequence[int] = range(0, rows, max(groups, 1))
    else:
        starts = groups
    cuts = sorted(
        {0, rows} | {starts[min(bisect.bisect_left(starts, i * rows // n), len(starts) - 1)] for i in range(1, n)}
    )
    return [(a, b) for a, b in itertools.pairwise(cuts) if b > a]


def _run(kernel: Any, ranges: list[tuple[int, int]], *args: Any) -> None:
    """``kernel(*args, start, stop)`` for every range, on the pool's threads when there are several."""
    if len(ranges) == 1:
        kernel(*args, *ranges[0])
        return
    _parallel([functools.partial(kernel, *args, a, b) for a, b in ranges])


def _parallel(jobs: Sequence[Callable[[], Any]]) -> None:
    global _pool
    if len(jobs) == 1:
        jobs[0]()
        return
    if _pool is None:
        _pool = ThreadPoolExecutor(max_workers=max(2, _CPUS), thread_name_prefix="areasearch-attn")
    for future in [_pool.submit(job) for job in jobs]:
        future.result()


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _forward_kernel(q, k, v, idx, out, w, start, stop):  # type: ignore[no-untyped-def]
    """Rows [start, stop): for graph g and its head m (query head h = g * M + m), softmax over the
    listed neighbours s of q[p, h] . k[s, h % Hk], applied to v[s, h % Hv]; w keeps the weights.
    The logits of a graph go to one small buffer whose exponentials are taken in one tight loop."""
    graphs, nk = idx.shape[1], idx.shape[2]
    heads, dk, dv, hk, hv = q.shape[1], q.shape[2], v.shape[2], k.shape[1], v.shape[1]
    m_per = heads // graphs
    lg = np.empty(nk * m_per, dtype=np.float32)  # logits of head m, neighbour j at m * nk + j
    for p in range(start, stop):
        for g in range(graphs):
            h0 = g * m_per
            for m in range(m_per):
                h = h0 + m
                kh = h % hk
                for j in range(nk):
                    s = idx[p, g, j]
                    a = np.float32(-1e30)
                    if s >= 0:
                        a = np.float32(0.0)
                        for d in range(dk):
                            a += q[p, h, d] * k[s, kh, d]
                    lg[m * nk + j] = a
                top = np.float32(-1e30)
                for j in range(nk):
                    top = max(top, lg[m * nk + j])
                for j in range(nk):
                    lg[m * nk + j] -= top
            for i in range(nk * m_per):
                lg[i] = np.exp(lg[i])
            for m in range(m_per):
                h = h0 + m
                vh = h % hv
                total = np.float32(0.0)
                for j in range(nk):
                    if idx[p, g, j] >= 0:
                        total += lg[m * nk + j]
                inv = np.float32(1.0) / total if total > 0 else np.float32(0.0)  # no neighbour: 0
                for d in range(dv):
                    out[p, h, d] = 0.0
                for j in range(nk):
                    s = idx[p, g, j]
                    a = lg[m * nk + j] * inv if s >= 0 else np.float32(0.0)
                    w[p, h, j] = a
                    if s >= 0:
                        for d in range(dv):
                            out[p, h, d] += a * v[s, vh, d]


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _backward_kernel(q, k, v, idx, w, grad, gq, gk, gv, start, stop):  # type: ignore[no-untyped-def]
    """Gradients of :func:`_forward_kernel` for rows [start, stop): gq written, gk and gv accumulated.
    A row's query, incoming gradient and query gradient live in small local arrays (the compiler
    cannot tell that they do not alias the scattered sums, and would reload them)."""
    graphs, nk = idx.shape[1], idx.shape[2]
    heads, dk, dv, hk, hv = q.shape[1], q.shape[2], v.shape[2], k.shape[1], v.shape[1]
    m_per = heads // graphs
    gw = np.empty(nk, dtype=np.float32)
    gg = np.empty(dv, dtype=np.float32)
    qq = np.empty(dk, dtype=np.float32)
    acc_q = np.empty(dk, dtype=np.float32)
    for p in range(start, stop):
        for h in range(heads):
            g = h // m_per
            kh, vh = h % hk, h % hv
            for d in range(dv):
                gg[d] = grad[p, h, d]
            for d in range(dk):
                qq[d] = q[p, h, d]
                acc_q[d] = 0.0
            dot = np.float32(0.0)
            for j in range(nk):
                s = idx[p, g, j]
                if s < 0:
                    gw[j] = 0.0
                    continue
                a = w[p, h, j]
                acc = np.float32(0.0)
                for d in range(dv):
                    acc += gg[d] * v[s, vh, d]
                for d in range(dv):
                    gv[s, vh, d] += a * gg[d]
                gw[j] = acc
                dot += a * acc
            for j in range(nk):
                s = idx[p, g, j]
                if s < 0:
                    continue
                gl = w[p, h, j] * (gw[j] - dot)  # softmax backward
                for d in range(dk):
                    acc_q[d] += gl * k[s, kh, d]
                for d in range(dk):
                    gk[s, kh, d] += gl * qq[d]
            for d in range(dk):
                gq[p, h, d] = acc_q[d]


def _np(t: Tensor) -> np.ndarray:
    return t.detach().numpy()


class _SparseAttention(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, q: Tensor, k: Tensor, v: Tensor, idx: Tensor, groups: int | Sequence[int]) -> Tensor:  # type: ignore[override]
        q, k, v = q.contiguous(), k.contiguous(), v.contiguous()
        out = q.new_empty(q.shape[0], q.shape[1], v.shape[2])
        w = q.new_empty(q.shape[0], q.shape[1], idx.shape[2])
        ranges = _threads(q.shape[0], groups)
        _run(_forward_kernel, ranges, _np(q), _np(k), _np(v), _fixed_numpy(idx), out.numpy(), w.numpy())
        ctx.save_for_backward(q, k, v, idx, w)
        ctx.ranges = ranges
        return out

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor, Tensor, Tensor, None, None]:  # type: ignore[override]
        q, k, v, idx, w = ctx.saved_tensors
        grad = grad.contiguous()
        gq = torch.empty_like(q)
        gk = torch.zeros_like(k)
        gv = torch.zeros_like(v)
        args = (_np(q), _np(k), _np(v), _fixed_numpy(idx), _np(w), _np(grad), gq.numpy(), gk.numpy(), gv.numpy())
        _run(_backward_kernel, ctx.ranges, *args)
        return gq, gk, gv, None, None


def sparse_attention(q: Tensor, k: Tensor, v: Tensor, idx: Tensor, groups: int | Sequence[int] = 0) -> Tensor:
    """Per head h of query row p, in graph g = h // (H / G): softmax over the listed neighbours j of
    q[p, h] . k[idx[p, g, j], h % Hk], weights applied to v[idx[p, g, j], h % Hv]. q (P, H, dk),
    k (S, Hk, dk), v (S, Hv, dv), idx (P, G, K) int64 (-1: none). Returns (P, H, dv); 0 where a graph
    has no neighbour. ``groups``: see the module docstring (0: one group, the calling thread only)."""
    if q.device.type != "cpu" or q.dtype != torch.float32:
        return sparse_attention_reference(q, k, v, idx)
    if not (torch.is_grad_enabled() and (q.requires_grad or k.requires_grad or v.requires_grad)):
        q, k, v = q.contiguous(), k.contiguous(), v.contiguous()
        out = q.new_empty(q.shape[0], q.shape[1], v.shape[2])
        w = q.new_empty(q.shape[0], q.shape[1], idx.shape[2])
        ranges = _threads(q.shape[0], groups or q.shape[0])
        _run(_forward_kernel, ranges, q.numpy(), k.numpy(), v.numpy(), _fixed_numpy(idx), out.numpy(), w.numpy())
        return out
    return _SparseAttention.apply(q, k, v, idx, groups or q.shape[0])  # type: ignore[no-any-return]


def sparse_attention_reference(q: Tensor, k: Tensor, v: Tensor, idx: Tensor) -> Tensor:
    """:func:`sparse_attention` in plain torch ops (gathers), for devices other than the CPU and for tests."""
    h = q.shape[1]
    idx = idx.repeat_interleave(h // idx.shape[1], dim=1)  # (P, H, K)
    ok = idx >= 0
    rows = idx.clamp(min=0)
    heads = torch.arange(h, device=idx.device)[None, :, None].expand_as(rows)
    kk = k[rows, heads % k.shape[1]]  # (P, H, K, dk)
    logits = (kk * q[:, :, None]).sum(-1).masked_fill(~ok, -1e9)
    w = torch.softmax(logits, dim=-1) * ok  # a head with no neighbour: all 0
    return (w[..., None] * v[rows, heads % v.shape[1]]).sum(2)


# ---------------------------------------------------------------------------------------------- MLP attention


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
                for i in range(a_dim):
                    z[i] = max(edge[r, i] + p_part[b, p, i] + q_part[b, q, i], np.float32(0.0))
                for m in range(heads):
                    logit = bias[m]
                    for i in range(a_dim):
                        logit += w[m, i] * z[i]
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
                for i in range(a_dim):
                    gz = dz[i] if z[i] > 0 else np.float32(0.0)
                    g_edge[r, i] = gz
                    g_ppart[b, p, i] += gz
                    g_qpart[b, q, i] += gz
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
    arrays = [_np(t) if t.dtype.is_floating_point else _fixed_numpy(t) for t in inputs]
    _run(
        _cross_forward_kernel, _threads(b * n_p * n_q // 4, 1, b), *arrays, np.float32(cap), *(t.numpy() for t in outs)
    )
    return inputs, outs


def _fixed_numpy(t: Tensor) -> np.ndarray:
    """A numpy view of a mask or index tensor that stays as it is for a whole forward pass (neighbour
    lists, pair masks), made once: the view is kept on the tensor."""
    view = getattr(t, "_areasearch_numpy", None)
    if view is None:
        view = t.contiguous().numpy() if t.is_contiguous() else t.contiguous().numpy().copy()
        if t.is_contiguous():
            t._areasearch_numpy = view  # type: ignore[attr-defined]
    return view  # type: ignore[no-any-return]


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
        ranges = _threads(b * n_p * n_q // 4, 1, b)
        g_edge = torch.zeros_like(edge)  # rows of pairs that are not allowed (if any) get 0
        g_pp, g_qp = torch.empty_like(p_part), torch.empty_like(q_part)
        g_vq, g_vp = torch.empty_like(vq), torch.empty_like(vp)
        g_w = weight.new_zeros(len(ranges), *weight.shape)
        g_b = bias.new_zeros(len(ranges), *bias.shape)
        fixed = [_np(x) if x.dtype.is_floating_point else _fixed_numpy(x) for x in ctx.saved_tensors[:9]]
        saved = [x.numpy() for x in (out_p, den_p, out_q, den_q, e, t, g_p, g_q, g_edge, g_pp, g_qp)]
        kernel: Any = _cross_backward_kernel
        common = (*fixed, np.float32(ctx.cap), *saved)
        _parallel(
            [
                functools.partial(kernel, *common, g_w[i].numpy(), g_b[i].numpy(), g_vq.numpy(), g_vp.numpy(), lo, hi)
                for i, (lo, hi) in enumerate(ranges)
            ]
        )
        g_vp_out = g_vp.flatten(2) if ctx.with_q else None
        return g_edge, None, g_pp, g_qp, g_w.sum(0), g_b.sum(0), None, g_vq.flatten(2), g_vp_out, None, None


def pair_rows(allowed: Tensor) -> tuple[Tensor, Tensor]:
    """The pair table of a mask ``allowed`` (B, P, Q): (rows (B, P, Q) int64, the row of each allowed
    pair in the table, -1 elsewhere; the (b, p, q) index tuple of the table's rows)."""
    index = allowed.nonzero(as_tuple=True)
    rows = torch.full(allowed.shape, -1, dtype=torch.long, device=allowed.device)
    rows[index] = torch.arange(index[0].numel(), device=allowed.device)
    return rows, torch.stack(index, dim=1)


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

    The allowed pairs (p, q) are the rows of a pair table: ``rows`` (B, P, Q) int64 gives a pair's
    row, -1 for a pair that is not allowed (:func:`pair_rows`), and ``edge`` (N, A) holds each
    row's edge term (the pair's projected edge features): only allowed pairs cost anything. Score of
    pair (p, q), head m: e = exp(cap * tanh(l / cap)), l = weight[m] . relu(edge[row] + p_part[p] +
    q_part[q]) + bias[m]. Returns ``out_p`` (B, P, S, M, dv / M): for each P node the e-weighted mean
    of the Q nodes' values ``vq`` (B, Q, dv) (head m reading the m-th slice), over all its Q nodes
    (slot 0) and, with ``kinds`` > 1, over those of each kind (slots 1 + kind[q]; ``kind`` (B, Q)
    int64, -1 in none); and ``out_q`` (B, Q, M, dv / M), each Q node's weighted mean of the P nodes'
    values ``vp`` (B, P, dv), or None without ``vp``. A node with no allowed pair (in a slot) gets 0.
    p_part (B, P, A), q_part (B, Q, A), weight (M, A), bias (M,). On the CPU, fused numba kernels
    (the B rows split among threads); elsewhere :func:`cross_attention_reference`."""
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


def _gather_pairs(edge: Tensor, rows: Tensor) -> Tensor:
    """(B, P, Q, A): each pair's row of ``edge``, 0 for pairs that are not allowed."""
    if edge.shape[0] == 0:
        return edge.new_zeros(*rows.shape, edge.shape[1])
    return edge[rows.clamp(min=0)] * (rows >= 0)[..., None]


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
    z = torch.relu(_gather_pairs(edge, rows) + p_part[:, :, None] + q_part[:, None])  # (B, P, Q, A)
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
                for i in range(a_dim):
                    z[i] = max(edge[r, i] + p_part[b, p, i] + q_part[b, q, i], np.float32(0.0))
                for m in range(heads):
                    logit = bias[m]
                    for i in range(a_dim):
                        logit += w[m, i] * z[i]
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
                for i in range(a_dim):
                    gz = dz[i] if z[i] > 0 else np.float32(0.0)
                    g_edge[r, i] = gz
                    g_ppart[b, p, i] += gz
                    g_qpart[b, q, i] += gz
    g_w[:] = acc_w
    g_bias[:] = acc_bias


def _pair_mlp_forward(*inputs: Tensor) -> tuple[list[Tensor], Tensor]:
    edge, rows, p_part, q_part, weight, bias = inputs
    b, n_p, n_q = rows.shape
    args = [t.detach().contiguous() for t in (edge, p_part, q_part, weight, bias)]
    out = edge.new_empty(b, n_p, n_q, weight.shape[0])
    saved = [args[0], rows, *args[1:]]
    arrays = [_np(t) if t.dtype.is_floating_point else _fixed_numpy(t) for t in saved]
    _run(_pair_mlp_forward_kernel, _threads(b * n_p * n_q // 4, 1, b), *arrays, out.numpy())
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
        ranges = _threads(b * n_p * n_q // 4, 1, b)
        g_edge = torch.zeros_like(edge)  # rows of pairs that are not allowed (if any) get 0
        g_pp, g_qp = torch.empty_like(p_part), torch.empty_like(q_part)
        acc = [t.new_zeros(len(ranges), *t.shape) for t in (weight, bias)]
        fixed = [_np(t) if t.dtype.is_floating_point else _fixed_numpy(t) for t in ctx.saved_tensors]
        common = (*fixed, grad.contiguous().numpy(), g_edge.numpy(), g_pp.numpy(), g_qp.numpy())
        kernel: Any = _pair_mlp_backward_kernel
        parts = [[t[i].numpy() for t in acc] for i in range(len(ranges))]
        jobs = [functools.partial(kernel, *common, *part, lo, hi) for part, (lo, hi) in zip(parts, ranges, strict=True)]
        _parallel(jobs)
        return g_edge, None, g_pp, g_qp, acc[0].sum(0), acc[1].sum(0)


def pair_mlp(edge: Tensor, rows: Tensor, p_part: Tensor, q_part: Tensor, weight: Tensor, bias: Tensor) -> Tensor:
    """An MLP of one hidden layer over the pairs of two node sets: out[b, p, q] = weight relu(edge[row]
    + p_part[b, p] + q_part[b, q]) + bias on the allowed pairs, 0 on the others (which cost nothing).
    ``rows`` (B, P, Q) int64 and ``edge`` (N, A) are a pair table as in :func:`cross_attention`;
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
    z = torch.relu(_gather_pairs(edge, rows) + p_part[:, :, None] + q_part[:, None])  # (B, P, Q, A)
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
    _run(
        _sinkhorn_forward_kernel,
        _threads(b * nr * nc // 4, 1, b),
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
        _run(
            _sinkhorn_backward_kernel, _threads(b * nr * nc // 4, 1, b), *arrays, grad.contiguous().numpy(), g_z.numpy()
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
