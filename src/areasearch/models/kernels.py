"""Shared machinery of the fused CPU kernels of the DA-HGNN network, its costliest parts. Each kernel is an
autograd function with a plain-torch reference (used on other devices and by the tests):

* :func:`~areasearch.models.self_attention.sparse_attention`: multi-head attention over neighbour lists
  (the self-graphs);
* :func:`~areasearch.models.cross_attention.cross_attention`: MLP attention between two node sets, both
  ways (the cross-graphs);
* :func:`~areasearch.models.affinity.pair_mlp`: an MLP over the pairs of two node sets (the affinity of
  the similarity measure);
* :func:`~areasearch.models.affinity.sinkhorn`: log-domain Sinkhorn iterations.

The pair kernels read the allowed pairs' edge terms from a pair table (one row per allowed pair,
:func:`pair_rows`) and skip the other pairs, and Sinkhorn skips rows and columns that are off, so
the padding of a batch of decisions of different sizes costs (almost) nothing. Per-thread sums of
shared gradients stay in thread-local arrays (threads adding into neighbouring memory would fight
over cache lines).

This module holds what the kernels share: the split of their rows among threads (:func:`row_ranges`,
:func:`run_ranges`, one thread pool), the numpy views of their inputs, the pair table, and the pair
MLP's score and the gradient of its hidden layer (:func:`pair_logit`, :func:`hidden_grad`), inlined
into the pair kernels, which compile to the same machine code as with these loops written out.

Threads: a kernel's rows are cut into contiguous ranges, one per thread, only where a group of rows may
start (``groups``, see :mod:`areasearch.models.self_attention`), so that a backward pass's scatter into
shared gradients is race-free.
"""

from __future__ import annotations

import bisect
import functools
import itertools
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


def row_ranges(work: int, groups: int | Sequence[int], rows: int | None = None) -> list[tuple[int, int]]:
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


def run_ranges(kernel: Any, ranges: list[tuple[int, int]], *args: Any) -> None:
    """``kernel(*args, start, stop)`` for every range, on the pool's threads when there are several."""
    if len(ranges) == 1:
        kernel(*args, *ranges[0])
        return
    run_jobs([functools.partial(kernel, *args, a, b) for a, b in ranges])


def run_jobs(jobs: Sequence[Callable[[], Any]]) -> None:
    """Every job, on the pool's threads when there are several; returns when all are done."""
    global _pool
    if len(jobs) == 1:
        jobs[0]()
        return
    if _pool is None:
        _pool = ThreadPoolExecutor(max_workers=max(2, _CPUS), thread_name_prefix="areasearch-attn")
    for future in [_pool.submit(job) for job in jobs]:
        future.result()


def as_numpy(t: Tensor) -> np.ndarray:
    """A numpy view of a CPU tensor, detached from autograd."""
    return t.detach().numpy()


def fixed_numpy(t: Tensor) -> np.ndarray:
    """A numpy view of a mask or index tensor that stays as it is for a whole forward pass (neighbour
    lists, pair masks), made once: the view is kept on the tensor."""
    view = getattr(t, "_areasearch_numpy", None)
    if view is None:
        view = t.contiguous().numpy() if t.is_contiguous() else t.contiguous().numpy().copy()
        if t.is_contiguous():
            t._areasearch_numpy = view  # type: ignore[attr-defined]
    return view  # type: ignore[no-any-return]


def pair_rows(allowed: Tensor) -> tuple[Tensor, Tensor]:
    """The pair table of a mask ``allowed`` (B, P, Q): (rows (B, P, Q) int64, the row of each allowed
    pair in the table, -1 elsewhere; the (b, p, q) index tuple of the table's rows)."""
    index = allowed.nonzero(as_tuple=True)
    rows = torch.full(allowed.shape, -1, dtype=torch.long, device=allowed.device)
    rows[index] = torch.arange(index[0].numel(), device=allowed.device)
    return rows, torch.stack(index, dim=1)


def gather_pairs(edge: Tensor, rows: Tensor) -> Tensor:
    """(B, P, Q, A): each pair's row of ``edge``, 0 for pairs that are not allowed."""
    if edge.shape[0] == 0:
        return edge.new_zeros(*rows.shape, edge.shape[1])
    return edge[rows.clamp(min=0)] * (rows >= 0)[..., None]


# ------------------------------------------------------------------------- the pair MLP, inlined


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy", inline="always")
def pair_logit(w, bias, z, m, a_dim):  # type: ignore[no-untyped-def]
    """Head ``m``'s score of a pair with hidden layer ``z`` (``a_dim`` wide): w[m] . z + bias[m]."""
    logit = bias[m]
    for i in range(a_dim):
        logit += w[m, i] * z[i]
    return logit


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy", inline="always")
def hidden_grad(dz, z, r, b, p, q, g_edge, g_ppart, g_qpart, a_dim):  # type: ignore[no-untyped-def]
    """Back through the relu of the hidden layer ``z`` = relu(edge[r] + p_part[b, p] + q_part[b, q]) of pair
    (p, q) of batch row b (pair-table row r): its gradient ``dz`` into g_edge[r] (set) and g_ppart[b, p],
    g_qpart[b, q] (added)."""
    for i in range(a_dim):
        gz = dz[i] if z[i] > 0 else np.float32(0.0)
        g_edge[r, i] = gz
        g_ppart[b, p, i] += gz
        g_qpart[b, q, i] += gz
