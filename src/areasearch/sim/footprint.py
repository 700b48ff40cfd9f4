"""The robot footprint's collision rule: a disc of radius ``r`` against square obstacle cells.

One rule, used by everything that decides where a robot may be (:meth:`World.step
<areasearch.sim.world.World.step>`, the scene's team region, the planners' inflated grids, the
primitive search):

* a robot centre at a point p is **clear** when the disc of radius ``r`` round p overlaps no
  obstacle cell, each cell the closed square it covers (touching is allowed);
* a move from a to b is clear when the disc swept along the segment a-b (a capsule) overlaps no
  obstacle cell: exactly, not at sample points, so no move can slip through a gap narrower than the
  footprint between two samples; and when it comes no nearer than two radii to any other robot
  (the others stand still while one moves: robots move one after another);
* a grid cell is **traversable** (:func:`footprint_offsets`, :func:`traversable`) when its centre is
  clear, and two neighbouring traversable cells (8-neighbours) are **joined** when the move between
  their centres is clear; the team's region is the largest set of joined cells
  (:func:`team_region`).

Ties (a disc exactly touching a square) count as clear on every side, with :data:`TOUCH_M` of
slack, so that the integer geometry of the grid (:func:`footprint_offsets`) and the floating point
geometry of the world (:func:`segment_hits`) agree on every cell centre.

Why hand-written: the rule is a few lines of geometry inside numba kernels that run per move; no
library checks a swept disc against a bitmap.
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np
from scipy import ndimage

TOUCH_M = 1e-9
"""Slack, metres: a disc that comes within ``radius - TOUCH_M`` of an obstacle square overlaps it."""


@functools.lru_cache(maxsize=32)
def footprint_offsets(cell_m: float, radius_m: float) -> np.ndarray:
    """(K, 2) int64 (dy, dx), nearest first (ties by dy, then dx), read-only: the displacements from
    a cell to the obstacle cells that a disc of ``radius_m`` on its centre overlaps (the cell square
    comes closer than the radius). A cell is traversable when no obstacle cell lies at any of them;
    stamping them round every obstacle cell inflates a grid to the cells where a centre may not be."""
    r = radius_m - TOUCH_M
    reach = int(math.ceil(r / cell_m + 0.5))
    dy, dx = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    gap_y = np.maximum(np.abs(dy) - 0.5, 0.0) * cell_m  # centre to the nearest point of the square
    gap_x = np.maximum(np.abs(dx) - 0.5, 0.0) * cell_m
    d2 = gap_y**2 + gap_x**2
    keep = d2 < r * r
    order = np.lexsort((dx[keep], dy[keep], d2[keep]))
    offsets = np.stack([dy[keep][order], dx[keep][order]], axis=1).astype(np.int64)
    offsets.flags.writeable = False
    return offsets


# ---------------------------------------------------------------------------------- kernels


@numba.njit(cache=True, nogil=True, inline="always")
def point_segment_d2(px: float, py: float, ax: float, ay: float, bx: float, by: float) -> float:
    """Squared distance from (px, py) to the segment a-b."""
    sx, sy = bx - ax, by - ay
    dx, dy = px - ax, py - ay
    length2 = sx * sx + sy * sy
    if length2 > 0.0:
        t = min(1.0, max(0.0, (dx * sx + dy * sy) / length2))
        dx -= t * sx
        dy -= t * sy
    return dx * dx + dy * dy


@numba.njit(cache=True, nogil=True, inline="always")
def _point_box_d2(px: float, py: float, x0: float, y0: float, x1: float, y1: float) -> float:
    gx = max(x0 - px, 0.0, px - x1)
    gy = max(y0 - py, 0.0, py - y1)
    return gx * gx + gy * gy


@numba.njit(cache=True, nogil=True)
def segment_box_d2(ax: float, ay: float, bx: float, by: float, x0: float, y0: float, x1: float, y1: float) -> float:
    """Squared distance between the segment a-b and the box [x0, x1] x [y0, y1].

    Zero when they meet (Liang-Barsky clipping); else the distance of two disjoint convex shapes is
    reached at a vertex of one of them: an end of the segment or a corner of the box."""
    dx, dy = bx - ax, by - ay
    t0, t1 = 0.0, 1.0
    meets = True
    for k in range(4):
        if k == 0:
            p, q = -dx, ax - x0
        elif k == 1:
            p, q = dx, x1 - ax
        elif k == 2:
            p, q = -dy, ay - y0
        else:
            p, q = dy, y1 - ay
        if p == 0.0:
            if q < 0.0:
                meets = False
                break
        else:
            t = q / p
            if p < 0.0:
                t0 = max(t0, t)
            else:
                t1 = min(t1, t)
            if t0 > t1:
                meets = False
                break
    if meets:
        return 0.0
    best = min(_point_box_d2(ax, ay, x0, y0, x1, y1), _point_box_d2(bx, by, x0, y0, x1, y1))
    best = min(best, point_segment_d2(x0, y0, ax, ay, bx, by))
    best = min(best, point_segment_d2(x1, y0, ax, ay, bx, by))
    best = min(best, point_segment_d2(x0, y1, ax, ay, bx, by))
    best = min(best, point_segment_d2(x1, y1, ax, ay, bx, by))
    return best


@numba.njit(cache=True, nogil=True)
def segment_hits(
    obstacles: np.ndarray,
    y0: int,
    x0: int,
    ox: float,
    oy: float,
    cell_m: float,
    ax: float,
    ay: float,
    bx: float,
    by: float,
    radius_m: float,
    outside_blocks: bool = True,
) -> bool:
    """Whether the disc of ``radius_m`` swept from (ax, ay) to (bx, by) (metres, map frame) overlaps
    an obstacle cell of ``obstacles`` (h, w) bool, a window of the map whose first cell is (y0, x0)
    (map cell (iy, ix) covers ``x in ox + [ix, ix + 1) * cell_m``); cells outside the window count
    as obstacles unless ``outside_blocks`` is False. For a robot standing still, pass a = b."""
    h, w = obstacles.shape
    r = radius_m - TOUCH_M
    r2 = r * r
    half = 0.5 * cell_m
    # a cell whose centre is this far from the segment is clear of it: the square lies within half
    # a diagonal of its centre (and one whose centre is nearer than r is hit)
    far2 = (r + half * math.sqrt(2.0)) ** 2
    iy0 = int(math.floor((min(ay, by) - r - oy) / cell_m)) - y0
    iy1 = int(math.floor((max(ay, by) + r - oy) / cell_m)) - y0
    ix0 = int(math.floor((min(ax, bx) - r - ox) / cell_m)) - x0
    ix1 = int(math.floor((max(ax, bx) + r - ox) / cell_m)) - x0
    for iy in range(iy0, iy1 + 1):
        inside_y = 0 <= iy < h
        cy0 = oy + (iy + y0) * cell_m
        for ix in range(ix0, ix1 + 1):
            if inside_y and 0 <= ix < w:
                if not obstacles[iy, ix]:
                    continue
            elif not outside_blocks:
                continue
            cx0 = ox + (ix + x0) * cell_m
            d2 = point_segment_d2(cx0 + half, cy0 + half, ax, ay, bx, by)
            if d2 < r2:
                return True
            if d2 < far2 and segment_box_d2(ax, ay, bx, by, cx0, cy0, cx0 + cell_m, cy0 + cell_m) < r2:
                return True
    return False


@numba.njit(cache=True, nogil=True)
def _overlap_kernel(
    obstacles: np.ndarray, centre_m: np.ndarray, radius_m: float, cell_m: float, offsets: np.ndarray, out: np.ndarray
) -> None:
    """``out`` = a disc of ``radius_m`` on the cell's centre overlaps an obstacle cell (off the grid
    counts), ``offsets`` being :func:`footprint_offsets` of that radius. ``centre_m`` is the distance
    from each cell centre to the nearest obstacle cell's centre: the nearest point of that square is
    at most half a diagonal nearer, so only cells between the two bounds need their offsets tried."""
    h, w = obstacles.shape
    near = radius_m - TOUCH_M
    far = near + cell_m * math.sqrt(0.5)
    for iy in range(h):
        for ix in range(w):
            d = centre_m[iy, ix]
            if d < near:
                out[iy, ix] = True
                continue
            if d >= far:
                out[iy, ix] = False
                continue
            hit = False
            for k in range(offsets.shape[0]):
                y = iy + offsets[k, 0]
                x = ix + offsets[k, 1]
                if y < 0 or x < 0 or y >= h or x >= w or obstacles[y, x]:
                    hit = True
                    break
            out[iy, ix] = hit


def _overlaps(obstacles: np.ndarray, centre_m: np.ndarray, cell_m: float, radius_m: float) -> np.ndarray:
    out = np.empty(obstacles.shape, dtype=bool)
    _overlap_kernel(obstacles, centre_m, radius_m, cell_m, footprint_offsets(cell_m, radius_m), out)
    return out


def _centre_distances(obstacles: np.ndarray, cell_m: float) -> np.ndarray:
    """(H, W) distance from each cell centre to the nearest obstacle cell's centre (off the grid
    included: the ring round it), metres."""
    ring = np.pad(np.asarray(obstacles, dtype=bool), 1, constant_values=True)
    return np.asarray(ndimage.distance_transform_edt(~ring))[1:-1, 1:-1] * cell_m


@numba.njit(cache=True, nogil=True)
def _find(parent: np.ndarray, i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@numba.njit(cache=True, nogil=True)
def _join_kernel(
    traversable: np.ndarray, shallow: np.ndarray, obstacles: np.ndarray, cell_m: float, radius_m: float
) -> np.ndarray:
    """(H * W,) int64 union-find roots of the traversable cells joined by clear moves between
    8-neighbour centres (-1 elsewhere). A move that starts in a deep cell (no obstacle within the
    radius plus a cell's diagonal of its centre, ``~shallow``) is clear without a test."""
    h, w = traversable.shape
    parent = np.full(h * w, -1, dtype=np.int64)
    for i in range(h * w):
        if traversable.ravel()[i]:
            parent[i] = i
    for iy in range(h):
        for ix in range(w):
            if not traversable[iy, ix]:
                continue
            for k in range(4):  # east, north-west, north, north-east: every pair once
                if k == 0:
                    ny, nx = iy, ix + 1
                elif k == 1:
                    ny, nx = iy + 1, ix - 1
                elif k == 2:
                    ny, nx = iy + 1, ix
                else:
                    ny, nx = iy + 1, ix + 1
                if ny >= h or nx < 0 or nx >= w or not traversable[ny, nx]:
                    continue
                if shallow[iy, ix] and shallow[ny, nx]:
                    ax, ay = (ix + 0.5) * cell_m, (iy + 0.5) * cell_m
                    bx, by = (nx + 0.5) * cell_m, (ny + 0.5) * cell_m
                    if segment_hits(obstacles, 0, 0, 0.0, 0.0, cell_m, ax, ay, bx, by, radius_m):
                        continue
                a, b = _find(parent, iy * w + ix), _find(parent, ny * w + nx)
                if a != b:
                    parent[max(a, b)] = min(a, b)
    for i in range(h * w):
        if parent[i] >= 0:
            parent[i] = _find(parent, i)
    return parent


# ---------------------------------------------------------------------------------- grids


def traversable(obstacles: np.ndarray, cell_m: float, radius_m: float) -> np.ndarray:
    """(H, W) bool: the cells whose centre is clear of every obstacle cell (off the grid counts as
    obstacle) for a disc of ``radius_m``."""
    obstacles = np.asarray(obstacles, dtype=bool)
    return ~_overlaps(obstacles, _centre_distances(obstacles, cell_m), cell_m, radius_m)


def covered(centres: np.ndarray, cell_m: float, radius_m: float) -> np.ndarray:
    """(H, W) bool: the cells that a disc of ``radius_m`` on the centre of some True cell of
    ``centres`` overlaps (the footprint's offsets are symmetric: a dilation by them)."""
    offsets = footprint_offsets(cell_m, radius_m)
    reach = int(np.abs(offsets).max()) if len(offsets) else 0
    structure = np.zeros((2 * reach + 1, 2 * reach + 1), dtype=bool)
    structure[offsets[:, 0] + reach, offsets[:, 1] + reach] = True
    return np.asarray(ndimage.binary_dilation(np.asarray(centres, dtype=bool), structure=structure))


def team_region(obstacles: np.ndarray, cell_m: float, radius_m: float) -> np.ndarray:
    """(H, W) bool: the largest set of traversable cells joined by clear moves between neighbouring
    centres (ties: the set whose first cell in row-major order comes first); all False if no cell
    is traversable."""
    obstacles = np.asarray(obstacles, dtype=bool)
    centre_m = _centre_distances(obstacles, cell_m)
    free = ~_overlaps(obstacles, centre_m, cell_m, radius_m)
    if not free.any():
        return free
    # deep: clear of every obstacle by a cell's diagonal more than the radius (moves from it are clear)
    shallow = _overlaps(obstacles, centre_m, cell_m, radius_m + cell_m * math.sqrt(2.0))
    roots = _join_kernel(free, shallow, obstacles, cell_m, radius_m)
    inside = roots >= 0
    sizes = np.bincount(roots[inside], minlength=roots.size)
    return (roots == int(np.argmax(sizes))).reshape(obstacles.shape) & free


def segment_clearance_reference(
    obstacles: np.ndarray, cell_m: float, a: tuple[float, float], b: tuple[float, float], samples: int = 2001
) -> float:
    """Plain reference for :func:`segment_hits` (window and origin at the map's corner): the least
    distance, metres, from ``samples`` points evenly spaced on the segment a-b to an obstacle square
    (cells off the grid included, a band of them round it). The true distance is at most this and at
    least this less half the spacing of the points. Slow; for tests."""
    pad = 1  # the nearest cell off the grid is in the first ring round it
    grid = np.pad(np.asarray(obstacles, dtype=bool), pad, constant_values=True)
    ys, xs = np.nonzero(grid)
    lo_x, lo_y = (xs - pad) * cell_m, (ys - pad) * cell_m
    t = np.linspace(0.0, 1.0, samples)[:, None]
    px, py = a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t
    gx = np.maximum(np.maximum(lo_x[None] - px, 0.0), px - (lo_x[None] + cell_m))
    gy = np.maximum(np.maximum(lo_y[None] - py, 0.0), py - (lo_y[None] + cell_m))
    return float(np.sqrt(gx * gx + gy * gy).min())
