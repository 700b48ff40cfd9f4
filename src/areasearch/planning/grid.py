"""The planning grid: where a robot centre may be, and the boxes and cell checks the planners share.

* :func:`planning_grid` — known obstacles inflated by the footprint, unknown cells passable
  (optionally only near explored cells), the robots' cells forced free, diagonal pinches opened so a
  4-neighbour march passes where 8-connected motion does. It is the plain reference of the windowed,
  64-cells-a-word :func:`areasearch.planning.window.window_grid` (``tests/planning/test_geodesic.py`` checks
  they agree).
* :class:`InflatedObstacles` — the inflated obstacles of a growing map, updated at the cost of the
  cells that changed.
* :class:`Box`, :func:`region_box` — a window of the grid and the bounding box of a region plus a
  margin, to crop the grid; :func:`check_cells` validates (N, 2) cell arrays;
  :func:`disc_offsets` the cells of a disc.

Units: cells are (iy, ix) integer indices (y northwards), lengths metres.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numba
import numpy as np

from ..sim.footprint import footprint_offsets


def clearance_threshold_m(cell_m: float, radius_m: float) -> float:
    """Farthest centre-to-obstacle-centre distance (metres) at which an obstacle cell can overlap a
    robot footprint on a cell centre: the radius plus the half-diagonal of a cell (an upper bound on
    the reach of :func:`~areasearch.sim.footprint.footprint_offsets`, the rule itself)."""
    return radius_m + cell_m * math.sqrt(0.5)


@numba.njit(cache=True, nogil=True)
def inflate_kernel(occupied: np.ndarray, offsets: np.ndarray, blocked: np.ndarray) -> None:
    """Inflate obstacles: set ``blocked`` (H, W) bool at every ``offsets`` (K, 2) integer
    displacement (e.g. :func:`disc_offsets`) of every True cell of ``occupied`` (H, W) bool, within
    the grid. Only sets cells: ``blocked`` keeps what it held."""
    h, w = occupied.shape
    for iy in range(h):
        for ix in range(w):
            if occupied[iy, ix]:
                for k in range(offsets.shape[0]):
                    y = iy + offsets[k, 0]
                    x = ix + offsets[k, 1]
                    if 0 <= y < h and 0 <= x < w:
                        blocked[y, x] = True


@numba.njit(cache=True, nogil=True, inline="always")
def _near_along_rows(mask: np.ndarray, m: int, out: np.ndarray) -> None:
    """``out[i, j]`` = some True ``mask[i, j']`` with ``|j - j'| <= m`` (a running scan each way along each row)."""
    h, w = mask.shape
    for iy in range(h):
        last = -(m + 1)
        for ix in range(w):
            if mask[iy, ix]:
                last = ix
            out[iy, ix] = ix - last <= m
        last = w + m + 1
        for ix in range(w - 1, -1, -1):
            if mask[iy, ix]:
                last = ix
            if last - ix <= m:
                out[iy, ix] = True


@numba.njit(cache=True, nogil=True)
def _near_kernel(mask: np.ndarray, m: int, out: np.ndarray) -> None:
    """``out`` = some True cell of ``mask`` within Chebyshev distance ``m`` (separable running scans:
    along the rows, then along the columns of that)."""
    rows = np.zeros(mask.shape, dtype=np.bool_)
    _near_along_rows(mask, m, rows)
    _near_along_rows(rows.T, m, out.T)


@numba.njit(cache=True, nogil=True)
def _open_diagonals_kernel(passable: np.ndarray) -> None:
    """Where two passable cells touch only diagonally (a 2x2 block with both other cells blocked),
    open one of the other two (the north-east one of a south-west/north-east pair, the north-west
    one of the other pair), so that 4-neighbour marching passes where 8-connected motion does.

    All blocks are judged on the same grid, then every cell so found is opened, until no such
    block is left: the result does not depend on the order of the blocks (nor on the window a
    grid is cut from), as the 64-cells-a-word version in :mod:`areasearch.planning.window` needs."""
    h, w = passable.shape
    opened = np.zeros((h, w), dtype=np.bool_)
    while True:
        count = 0
        for y in range(h - 1):
            for x in range(w - 1):
                a = passable[y, x]
                b = passable[y, x + 1]
                c = passable[y + 1, x]
                d = passable[y + 1, x + 1]
                if a and d and not b and not c:
                    opened[y, x + 1] = True
                    count += 1
                elif b and c and not a and not d:
                    opened[y, x] = True
                    count += 1
        if count == 0:
            return
        for y in range(h):
            for x in range(w):
                if opened[y, x]:
                    passable[y, x] = True
                    opened[y, x] = False


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
    footprint on its centre would overlap an occupied cell (the world's rule,
    :mod:`areasearch.sim.footprint`; computed by stamping :func:`~areasearch.sim.footprint.footprint_offsets`
    on each occupied cell, as there are few occupied cells). Unknown cells (``~explored``) are
    passable, as in the paper's action planner; with ``unknown_margin_m`` only those within that
    distance (Chebyshev, whole cells) of a ``margin_from`` cell (default: any explored cell;
    :mod:`areasearch.planning.candidates` passes the frontier cells) are (0: unknown space is impassable).
    ``keep_free`` (K, 2) cells (the robots' own cells) are forced passable, so that a robot is never
    walled in by the inflation of an obstacle it has just seen. Finally, where two passable cells
    touch only at a corner, one of the two cells beside them is opened: robots move in any
    direction (the world's reachable region is 8-connected) but the FMM stencil is 4-connected, and
    would otherwise find such a pinch closed.
    Raises ValueError for a ``keep_free`` cell outside the grid.
    """
    explored = np.asarray(explored, dtype=bool)
    occupied = np.asarray(occupied, dtype=bool)
    if explored.shape != occupied.shape or explored.ndim != 2:
        raise ValueError(f"explored {explored.shape} and occupied {occupied.shape} must be 2-D grids of one shape")
    blocked = np.zeros(occupied.shape, dtype=bool)
    if occupied.any():
        inflate_kernel(occupied, footprint_offsets(cell_m, radius_m), blocked)
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
        self.offsets = footprint_offsets(cell_m, radius_m)
        self.grid = np.zeros(shape, dtype=bool)
        """(H, W) bool: cells where the footprint on the centre overlaps an occupied cell (as last updated)."""
        self._seen = np.zeros(shape, dtype=bool)
        self._diff = np.empty(shape, dtype=bool)

    def update(self, occupied: np.ndarray) -> np.ndarray:
        """Bring :attr:`grid` up to date with ``occupied`` (H, W) bool and return it."""
        np.not_equal(occupied, self._seen, out=self._diff)
        if self._diff.any():
            changed = np.flatnonzero(self._diff)
            if self._seen.ravel()[changed].any():
                self.grid[:] = False
                inflate_kernel(occupied, self.offsets, self.grid)
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
