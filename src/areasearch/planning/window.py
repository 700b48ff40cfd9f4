"""The planning grid of a window of the map, 64 cells to a machine word.

:func:`window_grid` gives the window ``box`` of :func:`areasearch.planning.grid.planning_grid` (the
plain reference; ``tests/planning/test_geodesic.py`` checks they agree) at a cost in proportion to the window,
not the map: rows are packed 64 cells to a uint64 word and the numba kernel
(:func:`_window_bits_kernel`) handles most steps a word at a time, with the frontier cells (known
free, an unknown 4-neighbour) as the anchors of the unknown margin.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..sim.footprint import footprint_offsets
from .grid import Box

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
    :func:`~areasearch.planning.grid.planning_grid` on the whole map would give them (``margin_from`` =
    the frontier cells, ``keep_free`` = ``keep``), then with ``impassable`` blocked and ``keep`` freed again: unknown
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
    (:class:`~areasearch.planning.grid.InflatedObstacles`), to skip that step.
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
