"""The grid walk of a horizontal ray: every cell it crosses, in order (Amanatides & Woo 1987).

One walk serves every ray caster of the sensing pipeline: the depth renderer
(:func:`areasearch.sim.depth.render_column`), the mapper's carve along a column's ray
(:func:`areasearch.sim.mapper.carve_ray`) and the world's fused kernel, which runs both on one walk.
They must agree on the cells and on the floating-point distances exactly (the world's kernel
replays the renderer's walk for the mapper), so the walk's arithmetic lives here once.

Coordinates are grid cells: cell ``(iy, ix)`` covers ``[ix, ix + 1) x [iy, iy + 1)``; a ray starts
at ``(px, py)`` with a unit direction ``(dx, dy)`` and ``t`` is the distance along it, in cells.
:func:`ray_start` gives the state in the starting cell, :func:`ray_next` the state in the next cell
the ray enters; the caller decides when to stop (a distance, the grid's edge, an obstacle). Both are
inlined into their callers (numba ``inline="always"``), so the walk costs what a hand-written loop
does. :func:`ray_cells_reference` is the same walk in plain Python from first principles (the sorted
grid-line crossings), for the tests.

Why hand-written: a few lines of arithmetic inside numba kernels, called per image column; the
libraries that trace rays through grids (e.g. scikit-image's ``line``) rasterise lines, which is not
the set of cells a ray crosses.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np


class Ray(NamedTuple):
    """The walk's state in one cell."""

    ix: int
    iy: int
    """The cell the ray is in."""
    step_x: int
    step_y: int
    """+1 or -1: the direction the ray moves in x and y."""
    t_dx: float
    t_dy: float
    """Distance along the ray between two vertical (two horizontal) grid lines (inf if parallel)."""
    t_x: float
    t_y: float
    """Distance at which the ray crosses the next vertical (horizontal) grid line (inf if never)."""
    t_enter: float
    """Distance at which the ray entered this cell (0 in the starting cell)."""


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _axis_start(p: float, d: float) -> tuple[int, int, float, float]:
    """One axis of :func:`ray_start`: the cell index, step, distance between grid lines and
    distance to the first grid line, for coordinate ``p`` and direction component ``d``."""
    i = int(math.floor(p))
    step = 1 if d > 0 else -1
    t_d = abs(1.0 / d) if d != 0.0 else np.inf
    if d > 0:
        t = (i + 1 - p) * t_d
    elif d < 0:
        t = (p - i) * t_d
    else:
        t = np.inf
    return i, step, t_d, t


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def ray_start(px: float, py: float, dx: float, dy: float) -> Ray:
    """The walk's state in the cell holding ``(px, py)``, for a ray of unit direction ``(dx, dy)``."""
    ix, step_x, t_dx, t_x = _axis_start(px, dx)
    iy, step_y, t_dy, t_y = _axis_start(py, dy)
    return Ray(ix, iy, step_x, step_y, t_dx, t_dy, t_x, t_y, 0.0)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def ray_next(ray: Ray) -> Ray:
    """The walk's state in the next cell the ray enters (across the horizontal grid line on a tie)."""
    if ray.t_x < ray.t_y:
        return Ray(ray.ix + ray.step_x, ray.iy, ray.step_x, ray.step_y, ray.t_dx, ray.t_dy,
                   ray.t_x + ray.t_dx, ray.t_y, ray.t_x)  # fmt: skip
    return Ray(ray.ix, ray.iy + ray.step_y, ray.step_x, ray.step_y, ray.t_dx, ray.t_dy,
               ray.t_x, ray.t_y + ray.t_dy, ray.t_y)  # fmt: skip


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def ray_in_grid(ray: Ray, gh: int, gw: int) -> bool:
    """Whether the ray's cell lies on a grid of ``gh`` x ``gw`` cells."""
    return 0 <= ray.ix < gw and 0 <= ray.iy < gh


def ray_cells_reference(
    px: float, py: float, dx: float, dy: float, t_max: float, gh: int, gw: int
) -> list[tuple[int, int, float]]:
    """``(iy, ix, t_enter)`` of the cells a ray crosses, in order, up to the first one entered
    beyond ``t_max`` or off the ``gh`` x ``gw`` grid: the grid-line crossings in closed form, sorted
    (plain Python; the reference for :func:`ray_start` / :func:`ray_next`)."""
    crossings: list[tuple[float, int, int]] = []  # (t, axis: 0 = vertical line, 1 = horizontal, step)
    for axis, p, d in ((0, px, dx), (1, py, dy)):
        if d == 0.0:
            continue
        step = 1 if d > 0 else -1
        line = math.floor(p) + (1 if d > 0 else 0)
        while True:
            t = (line - p) / d
            if t > t_max:
                break
            crossings.append((t, axis, step))
            line += step
    crossings.sort(key=lambda c: (c[0], -c[1]))  # on a tie the horizontal line first, as the walk does
    ix, iy = math.floor(px), math.floor(py)
    cells = []
    t_enter = 0.0
    k = 0
    while t_enter <= t_max and 0 <= ix < gw and 0 <= iy < gh:
        cells.append((iy, ix, t_enter))
        if k == len(crossings):
            break
        t_enter, axis, step = crossings[k]
        k += 1
        if axis == 0:
            ix += step
        else:
            iy += step
    return cells
