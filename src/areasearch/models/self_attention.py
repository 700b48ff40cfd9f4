"""Sparse attention, the self-graphs' kernel of the DA-HGNN network (eqs. 6-8 of the paper, on a sparse graph).

Each query row attends, per head, to the source rows its neighbour list names: logits q . k, a
softmax over the listed neighbours, the weighted sum of their values. :func:`sparse_attention` is an
autograd function. On the CPU its forward and backward passes are fused numba kernels (no K-fold
copies of keys or values, the softmax inside the loop), run on up to ``torch.get_num_threads()``
threads over disjoint groups of rows (:mod:`areasearch.models.kernels`); elsewhere (CUDA) it is the
same computation in plain torch ops (:func:`sparse_attention_reference`, also the tests' reference).

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

from collections.abc import Sequence
from typing import Any

import numba
import numpy as np
import torch
from torch import Tensor

from .kernels import as_numpy, fixed_numpy, row_ranges, run_ranges


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


class _SparseAttention(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, q: Tensor, k: Tensor, v: Tensor, idx: Tensor, groups: int | Sequence[int]) -> Tensor:  # type: ignore[override]
        q, k, v = q.contiguous(), k.contiguous(), v.contiguous()
        out = q.new_empty(q.shape[0], q.shape[1], v.shape[2])
        w = q.new_empty(q.shape[0], q.shape[1], idx.shape[2])
        ranges = row_ranges(q.shape[0], groups)
        run_ranges(
            _forward_kernel, ranges, as_numpy(q), as_numpy(k), as_numpy(v), fixed_numpy(idx), out.numpy(), w.numpy()
        )
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
        args = (
            as_numpy(q),
            as_numpy(k),
            as_numpy(v),
            fixed_numpy(idx),
            as_numpy(w),
            as_numpy(grad),
            gq.numpy(),
            gk.numpy(),
            gv.numpy(),
        )
        run_ranges(_backward_kernel, ctx.ranges, *args)
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
        ranges = row_ranges(q.shape[0], groups or q.shape[0])
        run_ranges(_forward_kernel, ranges, q.numpy(), k.numpy(), v.numpy(), fixed_numpy(idx), out.numpy(), w.numpy())
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
