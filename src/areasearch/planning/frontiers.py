"""The frontier side of candidate extraction: frontier cells, their pieces and node cells, and the
information gain of a node (numba kernels, each with the plain rule it implements in its docstring;
``tests/planning/test_candidates.py`` checks them, the information gain against brute force).

* :func:`frontier_mask` — known-free cells with an unknown 4-neighbour;
* :func:`open_frontier_kernel` — the frontier cells whose unknown side a robot can reach;
* :func:`frontier_nodes_kernel` — 8-connected components of frontier cells cut into pieces of at
  most about ``cluster_m``, with the node cell of each piece;
* :func:`snap_kernel` — the passable cell nearest a cell within a disc;
* :func:`information_gain` — unknown cells within a radius of each node cell.

Used by :func:`areasearch.planning.candidates.extract_candidates`. Units: cells (iy, ix) int64.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .grid import check_cells


def frontier_mask(explored: np.ndarray, occupied: np.ndarray) -> np.ndarray:
    """(H, W) bool: explored free cells (``explored & ~occupied``) with at least one unknown
    (``~explored``) 4-neighbour. Cells beyond the grid's edge are not unknown."""
    explored = np.asarray(explored, dtype=bool)
    unknown = np.pad(~explored, 1)  # (H+2, W+2), the border is not unknown
    near_unknown = unknown[:-2, 1:-1] | unknown[2:, 1:-1] | unknown[1:-1, :-2] | unknown[1:-1, 2:]
    return explored & ~np.asarray(occupied, dtype=bool) & near_unknown


@numba.njit(cache=True, nogil=True, inline="always")
def _hop_search(
    start: int, ys: np.ndarray, xs: np.ndarray, index: np.ndarray, hop: np.ndarray, queue: np.ndarray
) -> tuple[int, int]:
    """Breadth-first search over the 8-connected cells of ``index`` (grid -> cell, -1: none) from cell
    ``start``, through the cells whose ``hop`` is -1, setting their hop distance from ``start``. The
    cells in the order found are ``queue[:count]``; returns (count, longest hop distance)."""
    h, w = index.shape
    hop[start] = 0
    queue[0] = start
    tail = 1
    head = 0
    longest = 0
    while head < tail:
        c = queue[head]
        head += 1
        d = hop[c]
        longest = max(longest, d)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                ny = ys[c] + dy
                nx = xs[c] + dx
                if 0 <= ny < h and 0 <= nx < w:
                    j = index[ny, nx]
                    if j >= 0 and hop[j] < 0:
                        hop[j] = d + 1
                        queue[tail] = j
                        tail += 1
    return tail, longest


@numba.njit(cache=True, nogil=True)
def frontier_nodes_kernel(
    frontier: np.ndarray, passable: np.ndarray, cell_m: float, cluster_m: float, offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cut the 8-connected components of ``frontier`` into pieces and give each its node cell, at
    the cost of one scan of the window plus work in proportion to the frontier cells. Returns per
    piece: size (P,), centroid (P, 2) float, node cell (P, 2) (-1 when none), size of its component (P,).

    Components are found in raster order; a component is cut into k = ceil(L / cluster_m) bands of
    hop distance from one end (the cell found last by a breadth-first search from its first cell),
    L = (longest hop distance + 1) cells. The node cell is the passable cell of the piece nearest
    its centroid (first in raster order on a tie), else the first passable cell of ``offsets``
    (nearest first) around the centroid's cell.
    """
    h, w = frontier.shape
    n = 0
    for y in range(h):
        for x in range(w):
            n += frontier[y, x]
    index = np.full((h, w), -1, dtype=np.int32)  # frontier cell -> its place in raster order
    ys = np.empty(n, dtype=np.int64)
    xs = np.empty(n, dtype=np.int64)
    k = 0
    for y in range(h):
        for x in range(w):
            if frontier[y, x]:
                index[y, x] = k
                ys[k] = y
                xs[k] = x
                k += 1
    hop = np.full(n, -1, dtype=np.int64)
    reach = np.full(n, -1, dtype=np.int64)  # hop distance from its component's first cell: -1 not found yet
    queue = np.empty(n, dtype=np.int64)
    piece = np.empty(n, dtype=np.int64)
    comp_size = np.empty(n, dtype=np.int64)
    n_pieces = 0
    for first in range(n):
        if reach[first] >= 0:
            continue
        # 1) the component, breadth first from its first cell
        size, _ = _hop_search(first, ys, xs, index, reach, queue)
        # 2) hop distances from its far end (the last cell found)
        _, longest = _hop_search(queue[size - 1], ys, xs, index, hop, queue)
        span = longest + 1
        bands = max(1, min(span, int(math.ceil(span * cell_m / cluster_m - 1e-9))))
        for q in range(size):
            c = queue[q]
            piece[c] = n_pieces + hop[c] * bands // span
        for b in range(bands):
            comp_size[n_pieces + b] = size
        n_pieces += bands
    sizes = np.zeros(n_pieces, dtype=np.int64)
    centroid = np.zeros((n_pieces, 2))
    for c in range(n):
        p = piece[c]
        sizes[p] += 1
        centroid[p, 0] += ys[c]
        centroid[p, 1] += xs[c]
    for p in range(n_pieces):
        centroid[p, 0] /= sizes[p]
        centroid[p, 1] /= sizes[p]
    node = np.full((n_pieces, 2), -1, dtype=np.int64)
    best = np.full(n_pieces, np.inf)
    for c in range(n):  # raster order: the first cell wins a tie
        p = piece[c]
        if passable[ys[c], xs[c]]:
            d2 = (ys[c] - centroid[p, 0]) ** 2 + (xs[c] - centroid[p, 1]) ** 2
            if d2 < best[p]:
                best[p] = d2
                node[p, 0] = ys[c]
                node[p, 1] = xs[c]
    for p in range(n_pieces):
        if node[p, 0] < 0:
            cy = int(round(centroid[p, 0]))
            cx = int(round(centroid[p, 1]))
            for k in range(offsets.shape[0]):
                y = cy + offsets[k, 0]
                x = cx + offsets[k, 1]
                if 0 <= y < h and 0 <= x < w and passable[y, x]:
                    node[p, 0] = y
                    node[p, 1] = x
                    break
    return sizes, centroid, node, comp_size[:n_pieces].copy()


@numba.njit(cache=True, nogil=True)
def snap_kernel(passable: np.ndarray, cells: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(N, 2) the first passable cell of ``offsets`` (nearest first) around each cell; -1 if none."""
    h, w = passable.shape
    out = np.full((cells.shape[0], 2), -1, dtype=np.int64)
    for i in range(cells.shape[0]):
        for k in range(offsets.shape[0]):
            y = cells[i, 0] + offsets[k, 0]
            x = cells[i, 1] + offsets[k, 1]
            if 0 <= y < h and 0 <= x < w and passable[y, x]:
                out[i, 0] = y
                out[i, 1] = x
                break
    return out


@numba.njit(cache=True, nogil=True)
def _gain_kernel(explored: np.ndarray, cells: np.ndarray, radius_cells: float) -> np.ndarray:
    """(N,) number of unknown (not ``explored``) cells whose centres lie within ``radius_cells`` of
    each cell's centre: per-row running counts of the rows the discs cover, then two lookups per
    disc row."""
    gh, gw = explored.shape
    r = int(math.floor(radius_cells))
    y0, y1 = gh, 0
    x0, x1 = gw, 0
    for i in range(cells.shape[0]):
        y0, y1 = min(y0, cells[i, 0] - r), max(y1, cells[i, 0] + r + 1)
        x0, x1 = min(x0, cells[i, 1] - r), max(x1, cells[i, 1] + r + 1)
    y0, y1, x0, x1 = max(y0, 0), min(y1, gh), max(x0, 0), min(x1, gw)
    row_prefix = np.zeros((y1 - y0, x1 - x0 + 1), dtype=np.int32)  # unknown cells before x, per row
    for y in range(y0, y1):
        count = 0
        for x in range(x0, x1):
            count += not explored[y, x]
            row_prefix[y - y0, x - x0 + 1] = count
    out = np.zeros(cells.shape[0], dtype=np.int64)
    for i in range(cells.shape[0]):
        cy = cells[i, 0]
        cx = cells[i, 1]
        total = 0
        for dy in range(-r, r + 1):
            y = cy + dy
            if y < y0 or y >= y1:
                continue
            half = int(math.floor(math.sqrt(radius_cells * radius_cells - dy * dy)))
            lo = max(cx - half, x0)
            hi = min(cx + half + 1, x1)
            if hi > lo:
                total += row_prefix[y - y0, hi - x0] - row_prefix[y - y0, lo - x0]
        out[i] = total
    return out


def information_gain(explored: np.ndarray, cells: np.ndarray, radius_m: float, cell_m: float) -> np.ndarray:
    """(N,) float32: unknown cells (``~explored``) whose centres lie within ``radius_m`` of each cell."""
    explored = np.asarray(explored, dtype=bool)
    cells = check_cells(cells, explored.shape, "cells")
    if len(cells) == 0:
        return np.zeros(0, dtype=np.float32)
    return _gain_kernel(explored, cells, radius_m / cell_m).astype(np.float32)


@numba.njit(cache=True, nogil=True)
def open_frontier_kernel(
    frontier: np.ndarray, explored: np.ndarray, passable: np.ndarray, robots: np.ndarray, offsets: np.ndarray
) -> np.ndarray:
    """(h, w) bool: the frontier cells with an unknown 4-neighbour that a robot's footprint can
    reach, i.e. some passable cell joined to a robot cell (4-connected, as the FMM spreads) lies
    within ``offsets`` (the footprint radius plus half a cell's diagonal) of it. A frontier cell in a
    gap of a wall narrower than the footprint (a rasterised wall's missing pixel) has its unknown
    side beyond the wall: no robot can go and look there, so it is not open."""
    h, w = passable.shape
    reach = np.zeros((h, w), dtype=np.bool_)
    queue = np.empty(h * w, dtype=np.int64)
    tail = 0
    for i in range(robots.shape[0]):
        y, x = robots[i, 0], robots[i, 1]
        if 0 <= y < h and 0 <= x < w and passable[y, x] and not reach[y, x]:
            reach[y, x] = True
            queue[tail] = y * w + x
            tail += 1
    head = 0
    while head < tail:
        c = queue[head]
        head += 1
        y, x = c // w, c % w
        for k in range(4):
            ny = y + (k == 0) - (k == 1)
            nx = x + (k == 2) - (k == 3)
            if 0 <= ny < h and 0 <= nx < w and passable[ny, nx] and not reach[ny, nx]:
                reach[ny, nx] = True
                queue[tail] = ny * w + nx
                tail += 1
    out = np.zeros((h, w), dtype=np.bool_)
    for y in range(h):
        for x in range(w):
            if not frontier[y, x]:
                continue
            for k in range(4):
                uy = y + (k == 0) - (k == 1)
                ux = x + (k == 2) - (k == 3)
                if not (0 <= uy < h and 0 <= ux < w) or explored[uy, ux]:
                    continue
                for j in range(offsets.shape[0]):
                    ry = uy + offsets[j, 0]
                    rx = ux + offsets[j, 1]
                    if 0 <= ry < h and 0 <= rx < w and reach[ry, rx]:
                        out[y, x] = True
                        break
                if out[y, x]:
                    break
    return out
