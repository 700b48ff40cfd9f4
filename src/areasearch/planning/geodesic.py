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
* :func:`window_grid` — the planning grid of a window of the map (frontier cells as the margin's
  anchors), at a cost in proportion to the window: rows packed 64 cells to a machine word.
* :class:`InflatedObstacles` — the inflated obstacles of a growing map, updated at the cost of the
  cells that changed.

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
    goals are settled. On the bundled maps (``scene.free`` passable, random free sources, cells
    farther than 1 m from the source) it reaches the same cells as ``"skfmm"``, differs from it by
    0.2-0.4 % on average and at most 2.6 % (the largest differences at the 1 m cut, where skfmm's
    half-cell source contour still shows), is within about 0.5 % mean / 1.3 % max of the Euclidean
    distance in an empty room, and is about 4x faster; hence the default.
    ``tests/test_geodesic.py`` bounds the difference to skfmm (mean 1 %, max 5 %) and to Euclid
    (mean 1 %, max 2 %). Per-map figures and timings: see docs/performance.md.

Cropping: distances to candidates, which all lie in or next to the explored region, do not depend
on unknown space far from it, so :mod:`areasearch.planning.candidates` makes unknown cells passable only
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

from ..sim.footprint import footprint_offsets

Method = Literal["fmm", "skfmm"]
METHODS: tuple[Method, ...] = ("fmm", "skfmm")
DEFAULT_METHOD: Method = "fmm"

FMM_PAD = 2
"""Cells of the impassable (zero) border that :func:`fmm_kernel`'s flat grid must carry on every
side, so the kernel needs no bounds checks (two cells: the second-order stencil reads two cells
away). Cell (iy, ix) of an (h, w) grid is flat index ``(iy + FMM_PAD) * width + ix + FMM_PAD`` with
``width = w + 2 * FMM_PAD``."""


# ---------------------------------------------------------------------------------- planning grid


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


@numba.njit(cache=True, nogil=True)
def _open_diagonals_kernel(passable: np.ndarray) -> None:
    """Where two passable cells touch only diagonally (a 2x2 block with both other cells blocked),
    open one of the other two (the north-east one of a south-west/north-east pair, the north-west
    one of the other pair), so that 4-neighbour marching passes where 8-connected motion does.

    All blocks are judged on the same grid, then every cell so found is opened, until no such
    block is left: the result does not depend on the order of the blocks (nor on the window a
    grid is cut from), as the 64-cells-a-word version in :func:`_window_bits_kernel` needs."""
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


_ONE = np.uint64(1)
_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)


@numba.njit(cache=True, nogil=True, inline="always")
def _up(x: np.ndarray, row: int, k: int, s: int) -> np.uint64:
    """Word ``k`` of packed row ``x[row]`` moved ``s`` columns towards higher columns (bit c of the
    result is bit c - s of the row; zeros shift in)."""
    q, r = s // 64, s % 64
    src = k - q
    if src < 0:
        return np.uint64(0)
    if r == 0:
        return x[row, src]
    v = x[row, src] << np.uint64(r)
    if src > 0:
        v |= x[row, src - 1] >> np.uint64(64 - r)
    return v


@numba.njit(cache=True, nogil=True, inline="always")
def _down(x: np.ndarray, row: int, k: int, s: int) -> np.uint64:
    """Word ``k`` of packed row ``x[row]`` moved ``s`` columns towards lower columns (bit c of the
    result is bit c + s of the row; zeros shift in)."""
    q, r = s // 64, s % 64
    src = k + q
    nw = x.shape[1]
    if src >= nw:
        return np.uint64(0)
    if r == 0:
        return x[row, src]
    v = x[row, src] >> np.uint64(r)
    if src + 1 < nw:
        v |= x[row, src + 1] << np.uint64(64 - r)
    return v


@numba.njit(cache=True, nogil=True, inline="always")
def _span_mask(k: int, c0: int, c1: int) -> np.uint64:
    """Bits of word ``k`` for the columns [c0, c1)."""
    lo = max(c0 - 64 * k, 0)
    hi = min(c1 - 64 * k, 64)
    if hi <= lo:
        return np.uint64(0)
    width = hi - lo
    ones = _ALL if width == 64 else (_ONE << np.uint64(width)) - _ONE
    return ones << np.uint64(lo)


@numba.njit(cache=True, nogil=True)
def _window_bits_kernel(
    explored: np.ndarray,
    occupied: np.ndarray,
    inflated: np.ndarray,
    impassable: np.ndarray,
    valid: int,
    fr0: int,
    fr1: int,
    fc0: int,
    fc1: int,
    ry: int,
    rx: int,
    h: int,
    w: int,
    margin: int,
    keep: np.ndarray,
    passable: np.ndarray,
    frontier: np.ndarray,
) -> None:
    """The planning grid of a window of the map, 64 cells to a machine word (bit b of word k is
    column 64 k + b of the packed region), so most steps handle 64 cells at once.

    ``explored`` and ``occupied`` (ph, nw) cover the window grown by the margin and then by one
    cell, clipped to the map (``valid`` columns); the frontier cells are those of rows [fr0, fr1)
    and columns [fc0, fc1) (the window grown by the margin); ``inflated`` and ``impassable``
    ((0, nw): none) cover the window's h rows from column 0 of the region; the window is rows
    [ry, ry + h), columns [rx, rx + w) of the region, ``keep`` (K, 2) cells in region coordinates.
    Fills ``passable`` and ``frontier`` (h, nw), the words of the window's rows, as
    :func:`planning_grid` on the whole map would give them (``margin_from`` = the frontier cells,
    ``keep_free`` = ``keep``), then with ``impassable`` blocked and ``keep`` freed again: unknown
    cells passable within Chebyshev ``margin`` cells of a frontier cell (all of them when
    ``margin`` < 0), inflated obstacles blocked, diagonal pinches opened."""
    ph, nw = explored.shape
    unknown = np.empty((ph, nw), dtype=np.uint64)
    for y in range(ph):
        for k in range(nw):
            unknown[y, k] = ~explored[y, k] & _span_mask(k, 0, valid)
    fh = fr1 - fr0
    grown = np.zeros((fh, nw), dtype=np.uint64)  # frontier cells of the grown window
    for fy in range(fh):
        y = fy + fr0
        for k in range(nw):
            near_unknown = _up(unknown, y, k, 1) | _down(unknown, y, k, 1)
            if y > 0:
                near_unknown |= unknown[y - 1, k]
            if y + 1 < ph:
                near_unknown |= unknown[y + 1, k]
            grown[fy, k] = explored[y, k] & ~occupied[y, k] & near_unknown & _span_mask(k, fc0, fc1)
    for i in range(h):
        for k in range(nw):
            frontier[i, k] = grown[ry + i - fr0, k] & _span_mask(k, rx, rx + w)
    if margin >= 0:
        # Chebyshev dilation by the margin: along rows, then along columns, by doubling spans
        near = grown.copy()
        row = np.empty(nw, dtype=np.uint64)
        c = 0
        while c < margin:
            s = min(c + 1, margin - c)
            for fy in range(fh):
                for k in range(nw):
                    row[k] = near[fy, k] | _up(near, fy, k, s) | _down(near, fy, k, s)
                near[fy, :] = row
            c += s
        other = np.empty((fh, nw), dtype=np.uint64)
        c = 0
        while c < margin:
            s = min(c + 1, margin - c)
            for fy in range(fh):
                for k in range(nw):
                    v = near[fy, k]
                    if fy >= s:
                        v |= near[fy - s, k]
                    if fy + s < fh:
                        v |= near[fy + s, k]
                    other[fy, k] = v
            near, other = other, near
            c += s
        for i in range(h):
            for k in range(nw):
                passable[i, k] = ~inflated[i, k] & (explored[ry + i, k] | near[ry + i - fr0, k])
    else:
        for i in range(h):
            for k in range(nw):
                passable[i, k] = ~inflated[i, k]
    for i in range(h):
        for k in range(nw):
            passable[i, k] &= _span_mask(k, rx, rx + w)
    for j in range(keep.shape[0]):
        i, x = keep[j, 0] - ry, keep[j, 1] - rx
        if 0 <= i < h and 0 <= x < w:
            passable[i, (x + rx) // 64] |= _ONE << np.uint64((x + rx) % 64)
    # diagonal pinches, all blocks at once until none is left (see _open_diagonals_kernel)
    opened = np.zeros((h, nw), dtype=np.uint64)
    pairs = np.empty(nw, dtype=np.uint64)
    while True:
        count = 0
        for i in range(h - 1):
            for k in range(nw):
                a = passable[i, k]
                b = _down(passable, i, k, 1)
                c2 = passable[i + 1, k]
                d = _down(passable, i + 1, k, 1)
                blocks = _span_mask(k, rx, rx + w - 1)
                p1 = a & d & ~b & ~c2 & blocks  # open the cell east of the block's corner
                p2 = b & c2 & ~a & ~d & blocks  # open the block's corner
                pairs[k] = p1
                opened[i, k] |= p2
                if p1 or p2:
                    count += 1
            for k in range(nw):
                opened[i, k] |= _up_row(pairs, k)
        if count == 0:
            break
        for i in range(h):
            for k in range(nw):
                passable[i, k] |= opened[i, k]
                opened[i, k] = 0
    if impassable.shape[0] > 0:
        for i in range(h):
            for k in range(nw):
                passable[i, k] &= ~impassable[i, k]
        for j in range(keep.shape[0]):
            i, x = keep[j, 0] - ry, keep[j, 1] - rx
            if 0 <= i < h and 0 <= x < w:
                passable[i, (x + rx) // 64] |= _ONE << np.uint64((x + rx) % 64)


@numba.njit(cache=True, nogil=True, inline="always")
def _up_row(x: np.ndarray, k: int) -> np.uint64:
    """Word ``k`` of the packed row ``x`` moved one column towards higher columns."""
    v = x[k] << _ONE
    if k > 0:
        v |= x[k - 1] >> np.uint64(63)
    return v


@numba.njit(cache=True, nogil=True)
def _inflate_window_kernel(occupied: np.ndarray, offsets: np.ndarray, y0: int, x0: int, blocked: np.ndarray) -> None:
    """Mark ``blocked`` (h, w), the window at (y0, x0) of the map, at every ``offsets`` displacement
    of every occupied cell (those just outside the window too)."""
    gh, gw = occupied.shape
    h, w = blocked.shape
    reach = 0
    for k in range(offsets.shape[0]):
        reach = max(reach, abs(offsets[k, 0]), abs(offsets[k, 1]))
    for iy in range(max(y0 - reach, 0), min(y0 + h + reach, gh)):
        for ix in range(max(x0 - reach, 0), min(x0 + w + reach, gw)):
            if occupied[iy, ix]:
                for k in range(offsets.shape[0]):
                    y = iy + offsets[k, 0] - y0
                    x = ix + offsets[k, 1] - x0
                    if 0 <= y < h and 0 <= x < w:
                        blocked[y, x] = True


def _pack(cells: np.ndarray, words: int) -> np.ndarray:
    """(n, words) uint64 with bit b of word k = cell 64 k + b of each row of ``cells`` (n, m) bool."""
    packed = np.packbits(cells, axis=1, bitorder="little")
    out = np.zeros((cells.shape[0], 8 * words), dtype=np.uint8)
    out[:, : packed.shape[1]] = packed
    return out.view("<u8")


def _unpack(bits: np.ndarray, start: int, width: int) -> np.ndarray:
    """(n, width) bool: the cells [start, start + width) of each packed row of ``bits``."""
    cells = np.unpackbits(bits.view(np.uint8), axis=1, count=start + width, bitorder="little")
    return np.ascontiguousarray(cells[:, start:]).view(np.bool_)


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
    gh, gw = explored.shape
    h, w = box.shape
    offsets = footprint_offsets(cell_m, radius_m)
    margin = -1 if unknown_margin_m is None else int(math.floor(unknown_margin_m / cell_m + 1e-9))
    m = max(margin, 0)
    # the window grown by the margin (frontier cells there open unknown cells in the window),
    # grown by one more cell (their unknown neighbours), clipped to the map
    fy0, fy1, fx0, fx1 = max(box.y0 - m, 0), min(box.y1 + m, gh), max(box.x0 - m, 0), min(box.x1 + m, gw)
    py0, py1, px0, px1 = max(fy0 - 1, 0), min(fy1 + 1, gh), max(fx0 - 1, 0), min(fx1 + 1, gw)
    words = (px1 - px0 + 63) // 64
    rows, cols = slice(py0, py1), slice(px0, px1)
    window_rows = slice(box.y0, box.y1)
    if inflated is None:
        blocked = np.zeros((h, px1 - px0), dtype=np.bool_)
        _inflate_window_kernel(occupied, offsets, box.y0, px0, blocked)
        inflated_bits = _pack(blocked, words)
    else:
        inflated_bits = _pack(inflated[window_rows, cols], words)
    keep = np.zeros((0, 2), dtype=np.int64) if keep_free is None else np.asarray(keep_free, dtype=np.int64)
    passable = np.empty((h, words), dtype=np.uint64)
    frontier = np.empty((h, words), dtype=np.uint64)
    _window_bits_kernel(
        _pack(explored[rows, cols], words),
        _pack(occupied[rows, cols], words),
        inflated_bits,
        _NO_WORDS if impassable is None else _pack(impassable[window_rows, cols], words),
        px1 - px0,
        fy0 - py0,
        fy1 - py0,
        fx0 - px0,
        fx1 - px0,
        box.y0 - py0,
        box.x0 - px0,
        h,
        w,
        margin,
        keep.reshape(-1, 2) - np.array([py0, px0]),
        passable,
        frontier,
    )
    return _unpack(passable, box.x0 - px0, w), _unpack(frontier, box.x0 - px0, w)


_NO_WORDS = np.zeros((0, 1), dtype=np.uint64)


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
