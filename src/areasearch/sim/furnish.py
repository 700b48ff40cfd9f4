"""Obstacles of the procedural layouts: partition walls and furniture, placed only where free space
and the robot's configuration space stay connected.

:class:`Grid` holds one layout attempt's free cells, heights and configuration space (free cells
farther than the robot's clearance from any obstacle, :func:`cspace_of`); :meth:`Grid.try_place`
adds a block when both stay one piece. :func:`add_partitions` puts stub walls in open-plan zones,
:func:`add_furniture` blocks against walls, in corners and free-standing. Used by
:func:`areasearch.sim.layouts.generate_layout`; all the randomness comes from the ``rng`` argument.

Units: cells; rectangles (x0, y0, x1, y1) half-open; heights metres.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from .rooms import LayoutParams, Rect, to_cells, uniform_int

_FURN_SIDE_M = (0.4, 1.5)
_FURN_HEIGHT_M = (0.4, 1.0)

FOUR = ndimage.generate_binary_structure(2, 1)
"""4-connectivity (free space)."""
EIGHT = ndimage.generate_binary_structure(2, 2)
"""8-connectivity (the configuration space)."""


class Grid:
    """Mutable working state of one layout attempt."""

    def __init__(self, free: np.ndarray, height: np.ndarray, p: LayoutParams) -> None:
        self.free = free
        self.height = height
        self.p = p
        self.keepout = np.zeros_like(free)
        self.cspace = cspace_of(free, p)

    def try_place(self, rect: Rect, height: float, room: Rect, keep: float) -> bool:
        """Place an obstacle if free space and C-space stay connected.

        Connectivity is first checked locally: if the free cells on the ring
        around the block (resp. the C-space cells on the band just outside
        the region the block removes from the C-space) form one connected
        piece, every path through the block can be rerouted around it.  Only
        when that local test is inconclusive is the whole grid labelled.
        """
        x0, y0, x1, y1 = rect
        free, cs = self.free, self.cspace
        gh, gw = free.shape
        if x0 < 1 or y0 < 1 or x1 > gw - 1 or y1 > gh - 1:
            return False
        if not free[y0:y1, x0:x1].all() or self.keepout[y0:y1, x0:x1].any():
            return False
        # C-space update: cells within the robot clearance of the new block.
        r = self.p.cspace_thr_cells
        k = math.ceil(r) + 2
        wx0, wy0 = max(x0 - k, 0), max(y0 - k, 0)
        wx1, wy1 = min(x1 + k, gw), min(y1 + k, gh)
        xs = np.arange(wx0, wx1)[None, :]
        ys = np.arange(wy0, wy1)[:, None]
        dx = np.maximum(np.maximum(x0 - xs, xs - (x1 - 1)), 0)
        dy = np.maximum(np.maximum(y0 - ys, ys - (y1 - 1)), 0)
        dist = np.sqrt((dx * dx + dy * dy).astype(np.float64))
        near = dist <= r
        cs_win = cs[wy0:wy1, wx0:wx1] & ~near
        rx0, ry0, rx1, ry1 = room
        removed = cs[wy0:wy1, wx0:wx1] & near
        sub = removed[max(ry0 - wy0, 0) : max(ry1 - wy0, 0), max(rx0 - wx0, 0) : max(rx1 - wx0, 0)]
        before = int(np.count_nonzero(cs[ry0:ry1, rx0:rx1]))
        if before - int(np.count_nonzero(sub)) < keep * before:
            return False
        band = cs_win & (dist <= r + 1.5)
        if ndimage.label(band, structure=EIGHT)[1] > 1:
            full = cs.copy()
            full[wy0:wy1, wx0:wx1] = cs_win
            if ndimage.label(full, structure=EIGHT)[1] != 1:
                return False
        # Free space: ring of cells around the block (4-connectivity).
        ring = free[y0 - 1 : y1 + 1, x0 - 1 : x1 + 1].copy()
        ring[1:-1, 1:-1] = False
        if ndimage.label(ring, structure=FOUR)[1] > 1:
            full = free.copy()
            full[y0:y1, x0:x1] = False
            if ndimage.label(full, structure=FOUR)[1] != 1:
                return False
        free[y0:y1, x0:x1] = False
        cs[wy0:wy1, wx0:wx1] = cs_win
        self.height[y0:y1, x0:x1] = np.float32(height)
        return True


def cspace_of(free: np.ndarray, p: LayoutParams) -> np.ndarray:
    dist = ndimage.distance_transform_edt(free)
    return np.asarray(dist > p.cspace_thr_cells)


def add_partitions(g: Grid, room: Rect, rng: np.random.Generator, wall_height: float) -> None:
    """Stub partition walls attached to one side of an open-plan zone."""
    p = g.p
    x0, y0, x1, y1 = room
    w, h = x1 - x0, y1 - y0
    vertical = bool(rng.random() < (0.75 if w >= h else 0.25))
    if not vertical:  # work in (along, across) = (y, x)
        x0, y0, x1, y1 = y0, x0, y1, x1
        w, h = h, w
    spacing = to_cells(2.0, p.cell_m)
    gap = to_cells(1.2, p.cell_m)
    t = p.wall_t
    placed: list[int] = []
    for _ in range(int(rng.integers(1, 4))):
        lo, hi = x0 + spacing, x1 - spacing - t
        if hi < lo:
            return
        pos = uniform_int(rng, lo, hi)
        length = min(round(float(rng.uniform(0.35, 0.65)) * h), h - gap)
        from_start = bool(rng.random() < 0.5)
        if any(abs(pos - q) < spacing for q in placed) or length < gap:
            continue
        a0 = y0 if from_start else y1 - length
        rect: Rect = (pos, a0, pos + t, a0 + length)
        if not vertical:
            rect = (rect[1], rect[0], rect[3], rect[2])
        if g.try_place(rect, wall_height, room, 0.5):
            placed.append(pos)


def add_furniture(g: Grid, room: Rect, rng: np.random.Generator) -> None:
    p = g.p
    x0, y0, x1, y1 = room
    w, h = x1 - x0, y1 - y0
    area_m2 = w * h * p.cell_m**2
    n_max = min(4, int(area_m2 / 6.0))
    n = uniform_int(rng, n_max // 2, n_max)
    side_lo = to_cells(_FURN_SIDE_M[0], p.cell_m)
    side_hi = math.floor(_FURN_SIDE_M[1] / p.cell_m + 1e-9)
    clear = to_cells(0.5, p.cell_m)
    for _ in range(n):
        for _try in range(4):
            bw = uniform_int(rng, side_lo, side_hi)
            bh = uniform_int(rng, side_lo, side_hi)
            height = float(rng.uniform(*_FURN_HEIGHT_M))
            mode = float(rng.random())
            if bw > w - 2 * clear or bh > h - 2 * clear:
                continue
            if mode < 0.55:  # against one wall
                side = int(rng.integers(4))
                bx = uniform_int(rng, x0, x1 - bw)
                by = uniform_int(rng, y0, y1 - bh)
                if side == 0:
                    by = y0
                elif side == 1:
                    by = y1 - bh
                elif side == 2:
                    bx = x0
                else:
                    bx = x1 - bw
            elif mode < 0.75:  # in a corner
                bx = x0 if rng.random() < 0.5 else x1 - bw
                by = y0 if rng.random() < 0.5 else y1 - bh
            else:  # free-standing, away from the walls
                bx = uniform_int(rng, x0 + clear, x1 - bw - clear)
                by = uniform_int(rng, y0 + clear, y1 - bh - clear)
            height = min(max(height, _FURN_HEIGHT_M[0]), _FURN_HEIGHT_M[1])
            if g.try_place((bx, by, bx + bw, by + bh), height, room, 0.4):
                break
