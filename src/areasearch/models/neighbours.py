"""Neighbour lists of the sparse graphs of the DA-HGNN network, computed once per observation by
:mod:`areasearch.models.graph` (numba).

The large graphs of the network (:mod:`areasearch.models.network`) are sparse, K = ``neighbours``:
each candidate attends to its K nearest real candidates (itself included) in G_g and to its K
nearest of its own kind in G_e / G_c (``cand_nbr``, ``cand_kin``); each historical robot position to
its K nearest frontiers and its K nearest targets in G_r'e / G_r'c (``past_cand``); each historical
robot position and each historical goal to its K nearest of its own set in G_r' and G_g'
(``past_robot_nbr``, ``past_goal_nbr``). The lists are computed here, once per observation (numba),
-1 marking a missing neighbour. Ties in distance are broken by a canonical order of the nodes' own
features (position, kind, size, gain for candidates; position and age for history nodes), never by
their index, so permuting the candidates or the robots of an observation permutes the lists and
nothing else. With K at least the number of nodes the graphs are the paper's dense ones.
"""

from __future__ import annotations

import numba
import numpy as np


def canonical_rank(*keys: np.ndarray) -> np.ndarray:
    """Rank of each node in the lexicographic order of its ``keys`` (first key most significant):
    a tie-break that depends on the nodes' features only."""
    n = len(keys[0])
    rank = np.empty(n, dtype=np.float64)
    rank[np.lexsort(keys[::-1])] = np.arange(n)
    return rank


def nearest(
    query: np.ndarray,
    source: np.ndarray,
    source_rank: np.ndarray,
    query_ok: np.ndarray,
    source_ok: np.ndarray,
    k: int,
    query_group: np.ndarray | None = None,
    source_group: np.ndarray | None = None,
) -> np.ndarray:
    """(Q, k) indices of the k nearest ``source`` points (S, 2) to each ``query`` point (Q, 2), nearest
    first, over the ``source_ok`` sources (and, with groups, those of the query's group); ties in
    distance go to the lower ``source_rank``. -1 where fewer than k, and on rows not ``query_ok``."""
    qg = np.zeros(len(query), np.int64) if query_group is None else query_group.astype(np.int64)
    sg = np.zeros(len(source), np.int64) if source_group is None else source_group.astype(np.int64)
    return _nearest_kernel(
        query.astype(np.float64), source.astype(np.float64), source_rank.astype(np.float64),
        query_ok.astype(np.bool_), source_ok.astype(np.bool_), qg, sg, k,
    )  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _nearest_kernel(
    query: np.ndarray,
    source: np.ndarray,
    rank: np.ndarray,
    query_ok: np.ndarray,
    source_ok: np.ndarray,
    query_group: np.ndarray,
    source_group: np.ndarray,
    k: int,
) -> np.ndarray:
    """Per query: the (squared distance, rank) key of every allowed source, then insertion of the keys
    below the current k-th best into a sorted list of k."""
    nq, ns = query.shape[0], source.shape[0]
    out = np.full((nq, k), -1, dtype=np.int64)
    key = np.empty(ns, dtype=np.float64)
    best = np.empty(k, dtype=np.float64)
    scale = float(ns + 1)
    for i in range(nq):
        if not query_ok[i]:
            continue
        qy, qx, qg = query[i, 0], query[i, 1], query_group[i]
        for j in range(ns):
            dy = qy - source[j, 0]
            dx = qx - source[j, 1]
            ok = source_ok[j] and source_group[j] == qg
            key[j] = (dy * dy + dx * dx) * scale + rank[j] if ok else np.inf
        found = 0
        worst = np.inf
        for j in range(ns):
            v = key[j]
            if v >= worst:
                continue
            pos = found if found < k else k - 1
            while pos > 0 and best[pos - 1] > v:
                best[pos] = best[pos - 1]
                out[i, pos] = out[i, pos - 1]
                pos -= 1
            best[pos] = v
            out[i, pos] = j
            if found < k:
                found += 1
            if found == k:
                worst = best[k - 1]
    return out


def nearest_pair(
    xy: np.ndarray, rank: np.ndarray, ok: np.ndarray, kind: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """The candidates' k nearest real candidates, and their k nearest of the same kind (one pass)."""
    q = xy.astype(np.float64)
    return _nearest_pair_kernel(q, rank.astype(np.float64), ok.astype(np.bool_), kind.astype(np.int64), k)  # type: ignore[no-any-return]


@numba.njit(cache=True, nogil=True)
def _nearest_pair_kernel(
    xy: np.ndarray, rank: np.ndarray, ok: np.ndarray, kind: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    n = xy.shape[0]
    near = np.full((n, k), -1, dtype=np.int64)
    kin = np.full((n, k), -1, dtype=np.int64)
    best = np.empty(k, dtype=np.float64)
    best_kin = np.empty(k, dtype=np.float64)
    key = np.empty(n, dtype=np.float64)
    scale = float(n + 1)
    for i in range(n):
        if not ok[i]:
            continue
        for j in range(n):  # the keys first, in a loop without branches (vectorised), then the lists
            dy = xy[i, 0] - xy[j, 0]
            dx = xy[i, 1] - xy[j, 1]
            key[j] = (dy * dy + dx * dx) * scale + rank[j]
        found = found_kin = 0
        worst = worst_kin = np.inf
        for j in range(n):
            v = key[j]
            if (v >= worst and v >= worst_kin) or not ok[j]:
                continue
            if v < worst:
                found = _insert(near[i], best, found, k, v, j)
                if found == k:
                    worst = best[k - 1]
            if v < worst_kin and kind[j] == kind[i]:
                found_kin = _insert(kin[i], best_kin, found_kin, k, v, j)
                if found_kin == k:
                    worst_kin = best_kin[k - 1]
    return near, kin


@numba.njit(inline="always")
def _insert(out: np.ndarray, best: np.ndarray, found: int, k: int, v: float, j: int) -> int:
    """Insert (key v, index j) into the sorted first ``found`` of ``best`` / ``out`` (at most k kept)."""
    pos = found if found < k else k - 1
    while pos > 0 and best[pos - 1] > v:
        best[pos] = best[pos - 1]
        out[pos] = out[pos - 1]
        pos -= 1
    best[pos] = v
    out[pos] = j
    return found + 1 if found < k else k


def neighbour_lists(
    xy: np.ndarray,
    kind: np.ndarray,
    size: np.ndarray,
    gain: np.ndarray,
    cand_mask: np.ndarray,
    past_cells: list[np.ndarray],
    past_masks: list[np.ndarray],
    age: np.ndarray,
    k: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The neighbour lists of one observation's graph (module docstring): ``cand_nbr``, ``cand_kin``
    (C, k), ``past_cand`` (N, 2, k), ``past_robot_nbr``, ``past_goal_nbr`` (N, k), ties broken by the
    nodes' own features. Candidates: positions ``xy`` (C, 2), ``kind``, ``size``, ``gain`` (C,),
    ``cand_mask``; history nodes: the cells and masks of the historical robots, then of the historical
    goals, and their ``age`` (N,)."""
    rank = canonical_rank(xy[:, 0], xy[:, 1], kind, size, gain)
    cand_nbr, cand_kin = nearest_pair(xy, rank, cand_mask, kind, k)
    past_nbr = []
    for cells, mask in zip(past_cells, past_masks, strict=True):
        past_rank = canonical_rank(cells[:, 0], cells[:, 1], age)
        past_nbr.append(nearest(cells, cells, past_rank, mask, mask, k))
    robots_ok = past_masks[0]
    past_cand = np.stack(
        [nearest(past_cells[0], xy, rank, robots_ok, cand_mask & (kind == i), k) for i in (0, 1)], axis=1
    )  # (N, 2, K)
    return cand_nbr, cand_kin, past_cand, past_nbr[0], past_nbr[1]
