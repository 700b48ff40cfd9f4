"""The Fast Marching Method kernel (numba) and its plain reference (scikit-fmm).

:func:`fmm_kernel` is the ``"fmm"`` method of :mod:`areasearch.planning.geodesic` (the scheme, its
accuracy and speed are described there), run by :func:`run_fmm` on a grid padded by :data:`FMM_PAD`;
:func:`skfmm_fields` is the ``"skfmm"`` reference it is checked against (``tests/planning/test_geodesic.py``).
Path planners call :func:`fmm_kernel` directly on their own padded grids.

Units: distances in cells (times ``scale`` in the fields); cells are flat indices of the padded grid.
"""

from __future__ import annotations

import math

import numba
import numpy as np

FMM_PAD = 2
"""Cells of the impassable (zero) border that :func:`fmm_kernel`'s flat grid must carry on every
side, so the kernel needs no bounds checks (two cells: the second-order stencil reads two cells
away). Cell (iy, ix) of an (h, w) grid is flat index ``(iy + FMM_PAD) * width + ix + FMM_PAD`` with
``width = w + 2 * FMM_PAD``."""


_BUCKET_SCALE = 8.0
"""Buckets per cell of distance in the untidy priority queue (bucket width 1/8 cell)."""
_BUCKET_MASK = 31
"""The queue is a ring of 32 buckets: a march step adds at most one cell (8 buckets) of distance."""


@numba.njit(cache=True, nogil=True, inline="always")
def _solve(done: np.ndarray, j: int, width: int) -> float:
    """Upwind solution of |grad T| = 1 (unit cells) at cell ``j`` from its settled neighbours.

    ``done`` holds settled distances and +inf elsewhere. Along each axis the smaller settled
    neighbour is used, by the one-sided second-order difference (3T - 4t1 + t2) / 2 when the next
    cell beyond it is settled and not larger, by the first-order difference T - t1 otherwise.
    """
    inf = np.inf
    left = done[j - 1]
    right = done[j + 1]
    vx = min(left, right)
    x2 = done[j - 2] if left <= right else done[j + 2]
    cx = 1.0
    if x2 <= vx < inf:
        vx = vx + (vx - x2) * (1.0 / 3.0)
        cx = 2.25
    down = done[j - width]
    up = done[j + width]
    vy = min(down, up)
    y2 = done[j - 2 * width] if down <= up else done[j + 2 * width]
    cy = 1.0
    if y2 <= vy < inf:
        vy = vy + (vy - y2) * (1.0 / 3.0)
        cy = 2.25
    if vy < vx:
        vx, vy = vy, vx
        cx, cy = cy, cx
    sol = vx + (1.0 if cx == 1.0 else 2.0 / 3.0)
    if sol > vy:  # both axes are upwind: cx (T - vx)^2 + cy (T - vy)^2 = 1
        # with d = vy - vx and T = vx + u: (cx + cy) u² - 2 cy d u + cy d² - 1 = 0
        d = vy - vx
        a = cx + cy
        disc = a - cx * cy * d * d
        sol = vx + (cy * d + math.sqrt(max(disc, 0.0))) / a
    return sol


@numba.njit(cache=True, nogil=True)
def fmm_kernel(
    passable: np.ndarray,
    width: int,
    sources: np.ndarray,
    goals: np.ndarray,
    stop: bool,
    fields: np.ndarray,
    scale: float,
    at_goals: np.ndarray,
) -> None:
    """Second-order FMM from each source over a padded flat grid (``passable`` uint8 (n,), row
    ``width`` cells long, with a border of :data:`FMM_PAD` zero cells), distances in cells.
    ``sources`` (N,) and ``goals`` (G,) int64 are flat indices into ``passable``. A source is
    settled at 0 whether or not its cell is passable (for the other sources it stays as it is).

    The narrow band is an untidy priority queue (Yatziv, Bartesaghi & Sapiro 2006): a ring of
    buckets 1/8 cell wide, so a push and a pop cost O(1); cells within one bucket leave in any order,
    which perturbs distances far less than the scheme's own error. A cell whose value drops within its
    bucket keeps its entry; one that moves to an earlier bucket gets a new entry, the old one is skipped.
    Distances are kept in float32 (a relative error of 1e-7 per step, far below the scheme's): half
    the memory traffic of float64, which the march is bound by.

    With ``stop`` each march ends once every goal is settled. ``at_goals`` (N, G) receives the goals'
    distances in cells, and ``fields`` (N, h, w) float32 (the grid without its border), unless it has
    no rows, every settled distance times ``scale`` (+inf elsewhere: unreached, or beyond the last
    goal when stopping).
    """
    n_cells = passable.shape[0]
    inf = np.float32(np.inf)
    done = np.empty(n_cells, dtype=np.float32)  # settled distances, +inf elsewhere
    tent = np.empty(n_cells, dtype=np.float32)  # tentative distances; < 0: blocked or settled
    slot = np.empty(n_cells, dtype=np.int32)  # bucket (unwrapped) of the cell's newest queue entry
    goal_count = np.zeros(n_cells, dtype=np.int32)
    reachable_goals = 0  # goals on passable cells: the others are never settled (+inf)
    for g in range(goals.shape[0]):
        goal_count[goals[g]] += 1
        reachable_goals += passable[goals[g]] != 0
    n_passable = 0
    for i in range(n_cells):
        n_passable += passable[i]
    cap = 4 * n_passable + 16  # a cell is pushed when its tentative value drops: at most 4 times
    entry_cell = np.empty(cap, dtype=np.int32)
    entry_next = np.empty(cap, dtype=np.int32)
    head = np.empty(_BUCKET_MASK + 1, dtype=np.int32)
    sqrt2 = math.sqrt(2.0)
    write_fields = fields.shape[0] > 0
    for s in range(sources.shape[0]):
        src = sources[s]
        for i in range(n_cells):
            done[i] = inf
            tent[i] = inf if passable[i] else -1.0
        head[:] = -1
        used = 0
        pending = 0
        remaining = reachable_goals - (goal_count[src] if passable[src] else 0)
        done[src] = 0.0
        tent[src] = -1.0
        # exact initial values on the 8 cells around the source (a diagonal only past two free cells)
        for oy in (-width, 0, width):
            for ox in (-1, 0, 1):
                j = src + oy + ox
                if j == src or not passable[j]:
                    continue
                if oy != 0 and ox != 0:
                    if not (passable[src + ox] and passable[src + oy]):
                        continue
                    value = sqrt2
                else:
                    value = 1.0
                tent[j] = value
                slot[j] = int(value * _BUCKET_SCALE)
                b = slot[j] & _BUCKET_MASK
                entry_cell[used] = j
                entry_next[used] = head[b]
                head[b] = used
                used += 1
                pending += 1
        cur = 0
        while pending > 0 and not (stop and remaining <= 0):
            b = cur & _BUCKET_MASK
            e = head[b]
            if e < 0:
                cur += 1
                continue
            head[b] = entry_next[e]
            pending -= 1
            i = entry_cell[e]
            t = tent[i]
            if t < 0.0:
                continue  # stale: settled through a newer entry
            tent[i] = -1.0
            done[i] = t
            remaining -= goal_count[i]
            for o in (1, -1, width, -width):
                j = i + o
                tj = tent[j]
                if tj >= 0.0:
                    value = _solve(done, j, width)
                    if value < tj:
                        tent[j] = value
                        nb = max(int(value * _BUCKET_SCALE), cur)
                        if tj < inf and nb == slot[j]:
                            continue  # its entry already waits in that bucket
                        slot[j] = nb
                        b = nb & _BUCKET_MASK
                        entry_cell[used] = j
                        entry_next[used] = head[b]
                        head[b] = used
                        used += 1
                        pending += 1
        if write_fields:
            for y in range(fields.shape[1]):
                base = (y + FMM_PAD) * width + FMM_PAD
                for x in range(fields.shape[2]):
                    fields[s, y, x] = done[base + x] * scale
        for g in range(goals.shape[0]):
            at_goals[s, g] = done[goals[g]]


def run_fmm(
    passable: np.ndarray, sources: np.ndarray, goals: np.ndarray, *, stop: bool, want_fields: bool, scale: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Run the kernel on the padded grid; returns (fields (N, H, W) float32 times ``scale``, or
    empty, at_goals (N, G) in cells)."""
    h, w = passable.shape
    width = w + 2 * FMM_PAD
    padded = np.zeros((h + 2 * FMM_PAD, width), dtype=np.uint8)
    padded[FMM_PAD:-FMM_PAD, FMM_PAD:-FMM_PAD] = passable
    src_flat = (sources[:, 0] + FMM_PAD) * width + sources[:, 1] + FMM_PAD
    goal_flat = ((goals[:, 0] + FMM_PAD) * width + goals[:, 1] + FMM_PAD).astype(np.int64)
    n = len(sources)
    fields = np.empty((n, h, w) if want_fields else (0, 0, 0), dtype=np.float32)
    at_goals = np.empty((n, len(goals)))
    fmm_kernel(padded.ravel(), width, src_flat.astype(np.int64), goal_flat, stop, fields, scale, at_goals)
    return fields, at_goals


def skfmm_fields(passable: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """Reference fields by scikit-fmm, in cells (see the module docstring for the phi convention)."""
    import skfmm  # the reference only: not needed by the default method

    out = np.full((len(sources), *passable.shape), np.inf)
    for s, (iy, ix) in enumerate(sources):
        mask = ~passable
        mask[iy, ix] = False
        phi = np.ones(passable.shape)
        phi[iy, ix] = -1.0
        try:
            dist = skfmm.distance(np.ma.MaskedArray(phi, mask), dx=1.0)
        except ValueError:  # no passable neighbour: no zero contour, only the source is reached
            out[s, iy, ix] = 0.0
            continue
        reached = ~np.ma.getmaskarray(dist)
        out[s][reached] = np.asarray(dist)[reached] + 0.5
        out[s, iy, ix] = 0.0
    return out
