"""Pipeline stage "candidates" (its metric): geodesic distances on the planning grid by the Fast Marching Method.

DA-HGNN ("Topological Planner", cross-graph edges) measures robot-to-candidate distances with the
Fast Marching Method (FMM); its action planner ("Action Planner and Execution", after NCM, Ye et
al. 2022) plans with FMM on the global occupancy map, unknown space traversable.

* :func:`planning_grid` — where a robot centre may be: known obstacles inflated by the footprint,
  unknown cells passable (optionally only near explored cells).
* :func:`distance_fields` — (N, H, W) distance from each source cell over passable cells;
  +inf where impassable or unreachable.
* :func:`distance_field` — one source; optionally the march stops once given cells (a path
  planner's start) are settled.
* :func:`distances_to` — (N, G) distances from sources to goal cells; the march stops once every
  goal is settled.
* :func:`region_box` — the bounding box of a region plus a margin, to crop the grid.

Units: cells are (iy, ix) integer indices (y northwards); distances are metres between cell centres
(the source cell is 0, its 4-neighbours ``cell_m``, its diagonal neighbours ``sqrt(2) cell_m``).
A source on an impassable cell is made passable for its own march.

Methods (``method=``):

``"skfmm"`` — the reference
    scikit-fmm (``skfmm.distance``, second order) on a masked array, impassable cells masked:
    phi = -1 on the source cell, +1 elsewhere. The zero contour then lies half a cell from the
    source centre, so half a cell is added to every distance (the source itself is 0). Cells
    skfmm leaves masked (not reached) are +inf.
``"fmm"`` — the default, our numba kernel
    The same second-order upwind scheme (4-neighbour stencil; per axis the smaller settled
    neighbour, by the one-sided second-order difference where the cell beyond it is settled and
    not larger, else first order), with exact Euclidean values on the 8 cells around the source,
    an untidy bucket queue (O(1) push and pop) instead of a heap, and early termination once the
    goals are settled. Difference to ``"skfmm"`` on bundled maps (``scene.free`` passable, 4
    random free source cells, over all reached cells farther than 1 m from the source):

    ==========================  ==========  =========  ==============================
    map (cells)                  mean rel.   max rel.   4 full fields: fmm / skfmm
    ==========================  ==========  =========  ==============================
    robotathome_sarmis (262x252)  0.31 %     2.6 %      6.3 ms / 27.7 ms
    bormann_lab_ipa_rooms3        0.38 %     2.6 %      4.6 ms / 23.5 ms
    giraff_home_delcegno          0.36 %     2.6 %      5.8 ms / 25.4 ms
    bormann_lab_ipa (489x492)     0.18 %     2.6 %      34.1 ms / 138.7 ms
    ==========================  ==========  =========  ==============================

    Both reach the same cells. The differences shrink with distance from the source: the largest
    are at the 1 m cut, where skfmm's half-cell source contour (its diagonal neighbour reads 1.71
    cells for sqrt(2)) still shows; on robotathome_sarmis 0.5 % of cells differ by more than 2 %.
    In an empty room, beyond 1 m, fmm is within 0.45 % mean / 1.3 % max of the Euclidean distance
    (skfmm 0.52 % / 1.2 %). Being about 4x faster and agreeing far inside the 3 % mean this project
    allows, ``"fmm"`` is the default; ``tests/test_geodesic.py`` bounds the difference to skfmm
    (mean 1 %, max 5 %) and to Euclid (mean 1 %, max 2 %).

Cropping: distances to candidates, which all lie in or next to the explored region, do not depend
on unknown space far from it, so :mod:`areasearch.candidates` makes unknown cells passable only
within a margin of a frontier cell (``planning_grid(..., unknown_margin_m=, margin_from=)``: the
unknown space just beyond the frontiers and small unseen holes in explored rooms, not the unknown
band behind every wall seen from one side) and runs on the bounding box of the explored region
grown by that margin (:func:`region_box`). No passable cell lies outside the box, so the
result equals the whole-grid result for that planning grid; what the margin gives up is shortcuts
through unexplored space deeper than the margin (a path is then longer, or rarely unreachable).
"""

from __future__ import annotations

import functools
import math
from typing import Literal, NamedTuple

import numba
import numpy as np

Method = Literal["fmm", "skfmm"]
METHODS: tuple[Method, ...] = ("fmm", "skfmm")
DEFAULT_METHOD: Method = "fmm"

_PAD = 2
"""Impassable border added around the grid so the kernel needs no bounds checks (two cells: the
second-order stencil reads two cells away)."""


# ---------------------------------------------------------------------------------- planning grid


def clearance_threshold_m(cell_m: float, radius_m: float) -> float:
    """Smallest centre-to-obstacle-centre distance (metres) that keeps a robot footprint clear of an
    obstacle cell: the radius plus the half-diagonal of a cell (the rule of ``Scene.traversable``,
    so that planned cells are cells the world lets a robot stand on)."""
    return radius_m + cell_m * math.sqrt(0.5)


@numba.njit(cache=True, nogil=True)
def _inflate_kernel(occupied: np.ndarray, offsets: np.ndarray, blocked: np.ndarray) -> None:
    """Mark ``blocked`` at every ``offsets`` (K, 2) displacement of every occupied cell."""
    h, w = occupied.shape
    for iy in range(h):
        for ix in range(w):
            if occupied[iy, ix]:
                for k in range(offsets.shape[0]):
                    y = iy + offsets[k, 0]
                    x = ix + offsets[k, 1]
                    if 0 <= y < h and 0 <= x < w:
                        blocked[y, x] = True


@numba.njit(cache=True, nogil=True)
def _near_kernel(mask: np.ndarray, m: int, out: np.ndarray) -> None:
    """``out`` = some True cell of ``mask`` within Chebyshev distance ``m`` (separable running scans)."""
    h, w = mask.shape
    rows = np.zeros((h, w), dtype=np.bool_)
    for iy in range(h):
        last = -(m + 1)
        for ix in range(w):
            if mask[iy, ix]:
                last = ix
            rows[iy, ix] = ix - last <= m
        last = w + m + 1
        for ix in range(w - 1, -1, -1):
            if mask[iy, ix]:
                last = ix
            if last - ix <= m:
                rows[iy, ix] = True
    for ix in range(w):
        last = -(m + 1)
        for iy in range(h):
            if rows[iy, ix]:
                last = iy
            out[iy, ix] = iy - last <= m
        last = h + m + 1
        for iy in range(h - 1, -1, -1):
            if rows[iy, ix]:
                last = iy
            if last - iy <= m:
                out[iy, ix] = True


@numba.njit(cache=True, nogil=True, inline="always")
def _open_block(passable: np.ndarray, y: int, x: int) -> int:
    """Open a cell of the 2x2 block at (y, x) if its passable cells touch only diagonally; returns
    the opened cell's column offset (0 or 1; it lies in row y), or -1 if nothing was opened."""
    a = passable[y, x]
    b = passable[y, x + 1]
    c = passable[y + 1, x]
    d = passable[y + 1, x + 1]
    if a and d and not b and not c:
        passable[y, x + 1] = True
        return 1
    if b and c and not a and not d:
        passable[y, x] = True
        return 0
    return -1


@numba.njit(cache=True, nogil=True)
def _open_diagonals_kernel(passable: np.ndarray) -> None:
    """Where two passable cells touch only diagonally (a 2x2 block with both other cells blocked),
    open one of the other two, so that 4-neighbour marching passes where 8-connected motion does.

    One raster pass over the blocks; an opened cell can make such a pinch in a block already
    passed, so the blocks around it are checked again at once (a small stack), until none is left."""
    h, w = passable.shape
    stack = np.empty((256, 2), dtype=np.int64)
    overflow = False
    for y in range(h - 1):
        for x in range(w - 1):
            if passable[y, x] == passable[y + 1, x + 1] and passable[y, x + 1] == passable[y + 1, x]:
                dx = _open_block(passable, y, x)
                if dx < 0:
                    continue
                n = 0
                cy, cx = y, x + dx
                while True:
                    # the blocks holding the opened cell (cy, cx)
                    for by in (cy - 1, cy):
                        for bx in (cx - 1, cx):
                            if 0 <= by < h - 1 and 0 <= bx < w - 1:
                                if n == stack.shape[0]:
                                    overflow = True
                                    continue
                                stack[n, 0] = by
                                stack[n, 1] = bx
                                n += 1
                    opened = False
                    while n > 0 and not opened:
                        n -= 1
                        by, bx = stack[n, 0], stack[n, 1]
                        ddx = _open_block(passable, by, bx)
                        if ddx >= 0:
                            cy, cx = by, bx + ddx
                            opened = True
                    if not opened:
                        break
    # a pinch the stack could not follow (a cascade of more than 64 openings) is caught by full passes
    changed = overflow
    while changed:
        changed = False
        for y in range(h - 1):
            for x in range(w - 1):
                if _open_block(passable, y, x) >= 0:
                    changed = True


@numba.njit(cache=True, nogil=True)
def _window_kernel(
    explored: np.ndarray,
    occupied: np.ndarray,
    inflated: np.ndarray,
    impassable: np.ndarray,
    y0: int,
    y1: int,
    x0: int,
    x1: int,
    margin: int,
    offsets: np.ndarray,
    keep: np.ndarray,
    passable: np.ndarray,
    frontier: np.ndarray,
) -> None:
    """The planning grid of the window [y0, y1) x [x0, x1) of a whole map, in one call.

    Fills ``passable`` and ``frontier`` (h, w) as :func:`planning_grid` on the whole map would
    (``margin_from`` = the frontier cells, ``keep_free`` = ``keep``), then blocks the
    ``impassable`` cells ((0, 0): none) and frees ``keep`` again, all restricted to the window:
    occupied cells just outside the window inflate into it, frontier cells just outside it open
    unknown cells inside it, and unknown neighbours outside the window count. ``margin`` < 0:
    every unknown cell is passable. ``inflated`` (H, W), unless (0, 0), holds the occupied cells
    already inflated by ``offsets`` (:class:`InflatedObstacles`), which saves the stamping.
    """
    gh, gw = explored.shape
    h = y1 - y0
    w = x1 - x0
    reach = 0
    for k in range(offsets.shape[0]):
        reach = max(reach, abs(offsets[k, 0]), abs(offsets[k, 1]))
    if inflated.shape[0] > 0:
        for y in range(h):
            for x in range(w):
                passable[y, x] = not inflated[y + y0, x + x0]
    else:
        passable[:, :] = True
        for iy in range(max(y0 - reach, 0), min(y1 + reach, gh)):
            for ix in range(max(x0 - reach, 0), min(x1 + reach, gw)):
                if occupied[iy, ix]:
                    for k in range(offsets.shape[0]):
                        y = iy + offsets[k, 0] - y0
                        x = ix + offsets[k, 1] - x0
                        if 0 <= y < h and 0 <= x < w:
                            passable[y, x] = False
    # frontier cells in the window grown by the margin (clipped to the map)
    m = max(margin, 0)
    fy0, fy1 = max(y0 - m, 0), min(y1 + m, gh)
    fx0, fx1 = max(x0 - m, 0), min(x1 + m, gw)
    fh, fw = fy1 - fy0, fx1 - fx0
    grown = np.zeros((fh, fw), dtype=np.bool_)
    for iy in range(fy0, fy1):
        for ix in range(fx0, fx1):
            if explored[iy, ix] and not occupied[iy, ix]:
                grown[iy - fy0, ix - fx0] = (
                    (iy > 0 and not explored[iy - 1, ix])
                    or (iy < gh - 1 and not explored[iy + 1, ix])
                    or (ix > 0 and not explored[iy, ix - 1])
                    or (ix < gw - 1 and not explored[iy, ix + 1])
                )
    frontier[:, :] = grown[y0 - fy0 : y0 - fy0 + h, x0 - fx0 : x0 - fx0 + w]
    if margin >= 0:
        # unknown cells are passable only within Chebyshev distance m of a frontier cell:
        # separable running scans, first along rows (into the window's columns), then columns
        near_row = np.zeros((fh, w), dtype=np.bool_)
        for fy in range(fh):
            last = -(m + 1)
            for fx in range(fw):
                if grown[fy, fx]:
                    last = fx
                x = fx + fx0 - x0
                if 0 <= x < w and fx - last <= m:
                    near_row[fy, x] = True
            last = fw + m + 1
            for fx in range(fw - 1, -1, -1):
                if grown[fy, fx]:
                    last = fx
                x = fx + fx0 - x0
                if 0 <= x < w and last - fx <= m:
                    near_row[fy, x] = True
        # columns, row-major: north then south scans with the last marked row per column
        near = np.zeros((h, w), dtype=np.bool_)
        last_row = np.full(w, -(m + 1), dtype=np.int64)
        for fy in range(fh):
            y = fy + fy0 - y0
            for x in range(w):
                if near_row[fy, x]:
                    last_row[x] = fy
                if 0 <= y < h and fy - last_row[x] <= m:
                    near[y, x] = True
        last_row[:] = fh + m + 1
        for fy in range(fh - 1, -1, -1):
            for x in range(w):
                if near_row[fy, x]:
                    last_row[x] = fy
            y = fy + fy0 - y0
            if 0 <= y < h:
                for x in range(w):
                    if not near[y, x] and last_row[x] - fy > m and not explored[y + y0, x + x0]:
                        passable[y, x] = False
    for k in range(keep.shape[0]):
        y = keep[k, 0] - y0
        x = keep[k, 1] - x0
        if 0 <= y < h and 0 <= x < w:
            passable[y, x] = True
    _open_diagonals_kernel(passable)
    if impassable.shape[0] > 0:
        for y in range(h):
            for x in range(w):
                if impassable[y + y0, x + x0]:
                    passable[y, x] = False
        for k in range(keep.shape[0]):
            y = keep[k, 0] - y0
            x = keep[k, 1] - x0
            if 0 <= y < h and 0 <= x < w:
                passable[y, x] = True


def window_grid(
    explored: np.ndarray,
    occupied: np.ndarray,
    box: Box,
    cell_m: float,
    radius_m: float,
    *,
    unknown_margin_m: float | None = None,
    keep_free: np.ndarray | None = None,
    impassable: np.ndarray | None = None,
    inflated: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(passable, frontier) (h, w) bool of the window ``box`` of the whole map's planning grid.

    ``passable`` equals ``planning_grid(explored, occupied, ..., unknown_margin_m=unknown_margin_m,
    margin_from=frontier_cells, keep_free=keep_free)[box.slices]`` on the whole map, then with the
    ``impassable`` (H, W) cells (e.g. a collision map) blocked and the ``keep_free`` cells freed
    again; ``frontier`` holds the frontier cells (known free, an unknown 4-neighbour). It costs time
    in proportion to the window, not the map. ``keep_free`` cells outside the window are ignored.
    ``inflated``: the map's occupied cells already inflated for this cell size and radius
    (:class:`InflatedObstacles`), to skip that step.
    """
    h, w = box.shape
    passable = np.empty((h, w), dtype=np.bool_)
    frontier = np.empty((h, w), dtype=np.bool_)
    margin = -1 if unknown_margin_m is None else int(math.floor(unknown_margin_m / cell_m + 1e-9))
    keep = np.zeros((0, 2), dtype=np.int64) if keep_free is None else np.asarray(keep_free, dtype=np.int64)
    _window_kernel(
        explored,
        occupied,
        _NO_CELLS if inflated is None else inflated,
        _NO_CELLS if impassable is None else impassable,
        box.y0,
        box.y1,
        box.x0,
        box.x1,
        margin,
        disc_offsets(clearance_threshold_m(cell_m, radius_m) / cell_m),
        keep.reshape(-1, 2),
        passable,
        frontier,
    )
    return passable, frontier


_NO_CELLS = np.zeros((0, 0), dtype=np.bool_)


@functools.lru_cache(maxsize=32)
def disc_offsets(radius_cells: float) -> np.ndarray:
    """(K, 2) int64 (dy, dx) with dy² + dx² <= radius², nearest first (ties by dy, then dx); read-only."""
    r = int(math.floor(radius_cells))
    dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
    d2 = dy**2 + dx**2
    keep = d2 <= radius_cells**2
    order = np.lexsort((dx[keep], dy[keep], d2[keep]))
    offsets = np.stack([dy[keep][order], dx[keep][order]], axis=1).astype(np.int64)
    offsets.flags.writeable = False
    return offsets


def planning_grid(
    explored: np.ndarray,
    occupied: np.ndarray,
    cell_m: float,
    radius_m: float,
    keep_free: np.ndarray | None = None,
    *,
    unknown_margin_m: float | None = None,
    margin_from: np.ndarray | None = None,
) -> np.ndarray:
    """(H, W) bool: cells where a robot centre may be planned.

    Known obstacles (``occupied``) are inflated by the footprint: a cell is blocked when the
    distance from its centre to the nearest occupied cell centre is at most
    :func:`clearance_threshold_m` (the Euclidean distance transform rule; computed by stamping a
    disc on each occupied cell, which gives the same cells at a fraction of the cost, as there are
    few occupied cells). Unknown cells (``~explored``) are passable, as in the paper's action
    planner; with ``unknown_margin_m`` only those within that distance (Chebyshev, whole cells) of
    a ``margin_from`` cell (default: any explored cell; :mod:`areasearch.candidates` passes the
    frontier cells) are (0: unknown space is impassable). ``keep_free`` (K, 2) cells (the robots'
    own cells) are forced passable, so that a robot is never walled in by the inflation of an
    obstacle it has just seen. Finally, where two passable cells touch only at a corner, one of the
    two cells beside them is opened: robots move in any direction (the world's reachable region is
    8-connected) but the FMM stencil is 4-connected, and would otherwise find such a pinch closed
    (the opened cell's clearance falls short of the threshold by less than a cell).
    Raises ValueError for a ``keep_free`` cell outside the grid.
    """
    explored = np.asarray(explored, dtype=bool)
    occupied = np.asarray(occupied, dtype=bool)
    if explored.shape != occupied.shape or explored.ndim != 2:
        raise ValueError(f"explored {explored.shape} and occupied {occupied.shape} must be 2-D grids of one shape")
    blocked = np.zeros(occupied.shape, dtype=bool)
    if occupied.any():
        _inflate_kernel(occupied, disc_offsets(clearance_threshold_m(cell_m, radius_m) / cell_m), blocked)
    passable = ~blocked
    if unknown_margin_m is not None:
        anchor = explored if margin_from is None else np.asarray(margin_from, dtype=bool)
        if anchor.shape != explored.shape:
            raise ValueError(f"margin_from {anchor.shape} must have the map's shape {explored.shape}")
        near = np.empty(explored.shape, dtype=bool)
        _near_kernel(anchor, int(math.floor(unknown_margin_m / cell_m + 1e-9)), near)
        passable &= explored | near
    if keep_free is not None:
        cells = check_cells(keep_free, passable.shape, "keep_free")
        passable[cells[:, 0], cells[:, 1]] = True
    _open_diagonals_kernel(passable)
    return passable


@numba.njit(cache=True, nogil=True)
def _stamp_kernel(cells: np.ndarray, width: int, offsets: np.ndarray, blocked: np.ndarray) -> None:
    """Mark ``blocked`` (H, W) at every ``offsets`` displacement of each flat cell index of ``cells``."""
    h, w = blocked.shape
    for c in cells:
        iy, ix = c // width, c % width
        for k in range(offsets.shape[0]):
            y = iy + offsets[k, 0]
            x = ix + offsets[k, 1]
            if 0 <= y < h and 0 <= x < w:
                blocked[y, x] = True


class InflatedObstacles:
    """Known obstacles inflated by the footprint (the rule of :func:`planning_grid`), kept up to
    date as the occupancy grid grows at the cost of the cells that changed, not of the map.

    :meth:`update` compares the occupancy grid with the one it last saw: new obstacle cells are
    stamped; an obstacle cell that disappeared (a reset, a hand-edited map) rebuilds everything.
    """

    def __init__(self, shape: tuple[int, int], cell_m: float, radius_m: float) -> None:
        self.offsets = disc_offsets(clearance_threshold_m(cell_m, radius_m) / cell_m)
        self.grid = np.zeros(shape, dtype=bool)
        """(H, W) bool: cells within the clearance threshold of an occupied cell (as last updated)."""
        self._seen = np.zeros(shape, dtype=bool)
        self._diff = np.empty(shape, dtype=bool)

    def update(self, occupied: np.ndarray) -> np.ndarray:
        """Bring :attr:`grid` up to date with ``occupied`` (H, W) bool and return it."""
        np.not_equal(occupied, self._seen, out=self._diff)
        if self._diff.any():
            changed = np.flatnonzero(self._diff)
            if self._seen.ravel()[changed].any():
                self.grid[:] = False
                _inflate_kernel(occupied, self.offsets, self.grid)
            else:
                _stamp_kernel(changed, occupied.shape[1], self.offsets, self.grid)
            np.copyto(self._seen, occupied)
        return self.grid


class Box(NamedTuple):
    """A window [y0, y1) x [x0, x1) of a grid, in cells."""

    y0: int
    y1: int
    x0: int
    x1: int

    @property
    def slices(self) -> tuple[slice, slice]:
        return slice(self.y0, self.y1), slice(self.x0, self.x1)

    @property
    def origin(self) -> np.ndarray:
        """(2,) int64 (iy, ix) of the box's first cell: subtract it from grid cells to get box cells."""
        return np.array([self.y0, self.x0], dtype=np.int64)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.y1 - self.y0, self.x1 - self.x0)


def region_box(
    mask: np.ndarray, margin: int, extra_cells: np.ndarray | None = None, *, shape: tuple[int, int] | None = None
) -> Box:
    """Bounding box of the True cells of ``mask`` and of ``extra_cells`` (K, 2), grown by ``margin``
    cells on every side and clipped to the grid. The whole grid if there is nothing to bound."""
    mask = np.asarray(mask, dtype=bool)
    h, w = shape if shape is not None else mask.shape
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    ys = [rows[0], rows[-1]] if len(rows) else []
    xs = [cols[0], cols[-1]] if len(cols) else []
    if extra_cells is not None and len(extra_cells):
        extra = np.asarray(extra_cells, dtype=np.int64).reshape(-1, 2)
        ys += [int(extra[:, 0].min()), int(extra[:, 0].max())]
        xs += [int(extra[:, 1].min()), int(extra[:, 1].max())]
    if not ys:
        return Box(0, h, 0, w)
    return Box(
        max(0, int(min(ys)) - margin),
        min(h, int(max(ys)) + margin + 1),
        max(0, int(min(xs)) - margin),
        min(w, int(max(xs)) + margin + 1),
    )


def check_cells(cells: np.ndarray, shape: tuple[int, ...], name: str) -> np.ndarray:
    """``cells`` as an (N, 2) int64 array of (iy, ix); ValueError naming ``name`` if it is not
    one or a cell lies outside a grid of ``shape``."""
    arr = np.asarray(cells)
    if arr.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.dtype.kind not in "iu":
        raise ValueError(f"{name} must be an (N, 2) integer array of (iy, ix) cells, got shape {arr.shape} {arr.dtype}")
    arr = arr.astype(np.int64, copy=False)
    outside = (arr[:, 0] < 0) | (arr[:, 0] >= shape[0]) | (arr[:, 1] < 0) | (arr[:, 1] >= shape[1])
    if outside.any():
        bad = arr[np.flatnonzero(outside)[0]]
        raise ValueError(
            f"{name}: cell (iy={bad[0]}, ix={bad[1]}) lies outside the {shape[0]}x{shape[1]} grid "
            f"({int(outside.sum())} of {len(arr)} cells outside)"
        )
    return arr


# ---------------------------------------------------------------------------------- numba FMM

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
def _fmm_kernel(
    passable: np.ndarray,
    width: int,
    sources: np.ndarray,
    goals: np.ndarray,
    stop: bool,
    fields: np.ndarray,
    scale: float,
    at_goals: np.ndarray,
) -> None:
    """Second-order FMM from each source over a padded flat grid (``passable`` uint8, a border of
    ``_PAD`` zero cells), distances in cells. A source is settled at 0 whether or not its cell is
    passable (for the other sources it stays as it is).

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
                base = (y + _PAD) * width + _PAD
                for x in range(fields.shape[2]):
                    fields[s, y, x] = done[base + x] * scale
        for g in range(goals.shape[0]):
            at_goals[s, g] = done[goals[g]]


def _prepare(passable: np.ndarray, sources: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    passable = np.asarray(passable, dtype=bool)
    if passable.ndim != 2:
        raise ValueError(f"passable must be a 2-D grid, got shape {passable.shape}")
    return passable, check_cells(sources, passable.shape, "sources")


def _run_fmm(
    passable: np.ndarray, sources: np.ndarray, goals: np.ndarray, *, stop: bool, want_fields: bool, scale: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Run the kernel on the padded grid; returns (fields (N, H, W) float32 times ``scale``, or
    empty, at_goals (N, G) in cells)."""
    h, w = passable.shape
    width = w + 2 * _PAD
    padded = np.zeros((h + 2 * _PAD, width), dtype=np.uint8)
    padded[_PAD:-_PAD, _PAD:-_PAD] = passable
    src_flat = (sources[:, 0] + _PAD) * width + sources[:, 1] + _PAD
    goal_flat = ((goals[:, 0] + _PAD) * width + goals[:, 1] + _PAD).astype(np.int64)
    n = len(sources)
    fields = np.empty((n, h, w) if want_fields else (0, 0, 0), dtype=np.float32)
    at_goals = np.empty((n, len(goals)))
    _fmm_kernel(padded.ravel(), width, src_flat.astype(np.int64), goal_flat, stop, fields, scale, at_goals)
    return fields, at_goals


def _skfmm_fields(passable: np.ndarray, sources: np.ndarray) -> np.ndarray:
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


def distance_fields(
    passable: np.ndarray, sources: np.ndarray, cell_m: float, *, method: Method = DEFAULT_METHOD
) -> np.ndarray:
    """(N, H, W) float32 geodesic distance in metres from each of ``sources`` (N, 2) cells.

    Over ``passable`` cells only (4-neighbour FMM stencil); +inf on impassable and unreachable
    cells. A source on an impassable cell is treated as passable for its own field. Raises
    ValueError when a source lies outside the grid.
    """
    passable, sources = _prepare(passable, sources)
    if method == "skfmm":
        cells = _skfmm_fields(passable, sources)
    elif method == "fmm":
        fields, _ = _run_fmm(
            passable, sources, np.zeros((0, 2), dtype=np.int64), stop=False, want_fields=True, scale=cell_m
        )
        return fields
    else:
        raise ValueError(f"unknown method {method!r}; use one of {', '.join(METHODS)}")
    return (cells * cell_m).astype(np.float32)


def distance_field(
    passable: np.ndarray,
    source: np.ndarray,
    cell_m: float,
    *,
    stop_at: np.ndarray | None = None,
    method: Method = DEFAULT_METHOD,
) -> np.ndarray:
    """(H, W) float32 geodesic distance in metres from one ``source`` cell (iy, ix).

    As :func:`distance_fields` for a single source. With ``stop_at`` (K, 2) cells the ``"fmm"``
    march ends once all of them are settled (a path planner's start): every cell nearer than the
    farthest of them is exact, farther cells may read +inf.
    """
    passable, sources = _prepare(passable, np.asarray(source).reshape(1, 2))
    if method == "fmm" and stop_at is not None:
        stops = check_cells(stop_at, passable.shape, "stop_at")
        fields, _ = _run_fmm(passable, sources, stops, stop=True, want_fields=True, scale=cell_m)
        return fields[0]
    return distance_fields(passable, sources, cell_m, method=method)[0]


def fields_to(
    passable: np.ndarray, sources: np.ndarray, goals: np.ndarray, cell_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Distance fields (N, H, W) and distances to the goals (N, G), float32 metres, by the ``"fmm"``
    method stopping once every goal is settled: the fields are exact wherever they are nearer than
    the farthest goal (so a path from any goal back to its source can be read off them)."""
    passable, sources = _prepare(passable, sources)
    goals = check_cells(goals, passable.shape, "goals")
    fields, cells = _run_fmm(passable, sources, goals, stop=True, want_fields=True, scale=cell_m)
    return fields, (cells * cell_m).astype(np.float32)


def distances_to(
    passable: np.ndarray,
    sources: np.ndarray,
    goals: np.ndarray,
    cell_m: float,
    *,
    method: Method = DEFAULT_METHOD,
) -> np.ndarray:
    """(N, G) float32 geodesic distance in metres from each source cell to each goal cell.

    Equals ``distance_fields(...)[:, goals[:, 0], goals[:, 1]]``; the ``"fmm"`` method stops each
    march as soon as every goal is settled. +inf for impassable or unreachable goals.
    """
    passable, sources = _prepare(passable, sources)
    goals = check_cells(goals, passable.shape, "goals")
    if method == "skfmm":
        cells = _skfmm_fields(passable, sources)[:, goals[:, 0], goals[:, 1]]
    elif method == "fmm":
        _, cells = _run_fmm(passable, sources, goals, stop=True, want_fields=False)
    else:
        raise ValueError(f"unknown method {method!r}; use one of {', '.join(METHODS)}")
    return (cells * cell_m).astype(np.float32)
