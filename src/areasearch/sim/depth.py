"""Pipeline stage "depth": a level pinhole depth camera rendered from the 2.5D scene.

The scene is a height field: every obstacle cell is a vertical prism from the floor (height 0)
up to ``height_m[iy, ix]``; free cells are bare floor. Each robot carries a camera at
``mount_height_m`` looking along its heading, with intrinsics from :class:`CameraConfig`
(square pixels, principal point at the image centre).

For a level pinhole camera all pixels of one image column lie in one vertical plane, so the
renderer walks one exact grid traversal (Amanatides & Woo 1987, :mod:`areasearch.sim.raycast`) per
column (:func:`render_column`) and, at each obstacle face, resolves the rows whose rays meet the face
below its top before they meet the floor.
Pixels see the floor, an obstacle face, or nothing within range.

Output: z-depth (distance along the optical axis) in metres, float32, shape (R, H, W); 0 marks
"no return" (the point is farther than ``max_range_m`` — Euclidean — or the ray leaves the scene).
Other robots are not rendered (they are not part of the height field).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numba
import numpy as np

from ..config import CameraConfig
from .raycast import ray_in_grid, ray_next, ray_start

GRAZE = 1e-4
"""Cells: a ray crossing less than this much of an obstacle cell's corner does not hit it (the
rendering rule; any other ray caster that must agree with the depth images uses it too)."""


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def camera_in_grid(
    poses: np.ndarray, r: int, origin_x: float, origin_y: float, cell_m: float
) -> tuple[float, float, float, float]:
    """Robot ``r``'s camera of ``poses`` (R, 3) on the grid: position (px, py) in cells and the
    cosine and sine of its heading."""
    px = (poses[r, 0] - origin_x) / cell_m
    py = (poses[r, 1] - origin_y) / cell_m
    return px, py, math.cos(poses[r, 2]), math.sin(poses[r, 2])


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def column_ray(cos_y: float, sin_y: float, xu: float) -> tuple[float, float, float]:
    """The horizontal ray of an image column of tangent ``xu`` for a camera heading (cos_y, sin_y):
    unit direction (dx, dy) and ``norm``, the horizontal metres per metre of z along it."""
    dx = cos_y + xu * sin_y  # forward + xu * right, right = (sin, -cos)
    dy = sin_y - xu * cos_y
    norm = math.sqrt(dx * dx + dy * dy)
    return dx / norm, dy / norm, norm


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def walk_buffers(s_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, t) arrays for the cells of one column's walk within ``s_max`` cells (at most
    ``s_max * sqrt(2) + 2`` cells; these hold more)."""
    cap = int(2.0 * s_max) + 8
    return np.empty(cap, dtype=np.int64), np.empty(cap, dtype=np.int64), np.empty(cap)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def render_column(
    height: np.ndarray,
    cell_m: float,
    px: float,
    py: float,
    dx: float,
    dy: float,
    norm: float,
    slope: np.ndarray,
    floor_depth: np.ndarray,
    z_max: np.ndarray,
    cam_h: float,
    s_max: float,
    h_max: float,
    out: np.ndarray,
    r: int,
    u: int,
    walk_x: np.ndarray,
    walk_y: np.ndarray,
    walk_t: np.ndarray,
) -> tuple[int, float]:
    """Render column ``u`` of image ``r`` into ``out`` (R, H, W) from the camera at grid point
    (px, py) whose column ray is (dx, dy, norm) (:func:`column_ray`); ``s_max`` is the range in cells.

    The cells the walk visits are recorded in order in ``walk_x``, ``walk_y`` and ``walk_t`` (where
    the ray enters each, cells; :func:`walk_buffers`). Returns their number and where the first cell
    the walk did not record begins (inf: off the grid)."""
    n_rows = out.shape[1]
    gh = height.shape[0]
    gw = height.shape[1]
    cap = walk_x.shape[0]
    for v in range(n_rows):
        out[r, v, u] = floor_depth[u, v]
    # Rows [0, top) are still open; rows below the floor boundary met the floor first.
    top = n_rows
    ray = ray_start(px, py, dx, dy)
    n_walk = 0
    while True:
        if ray.t_enter > s_max or n_walk == cap:
            return n_walk, ray.t_enter
        if not ray_in_grid(ray, gh, gw):
            return n_walk, np.inf
        walk_x[n_walk] = ray.ix
        walk_y[n_walk] = ray.iy
        walk_t[n_walk] = ray.t_enter
        n_walk += 1
        h = height[ray.iy, ray.ix]
        # a ray that only grazes a corner (less than GRAZE cells inside) passes by, so every
        # reported hit lies well inside its cell's face for the mapper
        if h > 0.0 and ray.t_enter > 0.0 and min(ray.t_x, ray.t_y) - ray.t_enter >= GRAZE:
            z_e = ray.t_enter * cell_m / norm
            # lowest row still above the floor at z_e: slope > -cam_h / z_e
            floor_slope = -cam_h / z_e
            top_slope = (h - cam_h) / z_e
            bot = top - 1
            while bot >= 0 and slope[bot] <= floor_slope:
                bot -= 1
            v = bot
            while v >= 0 and slope[v] <= top_slope:  # each row is hit once at most
                out[r, v, u] = z_e if z_e <= z_max[u, v] else 0.0
                v -= 1
            if v < bot:  # rows v+1 .. bot were hit; rows bot+1 .. top-1 see the floor
                top = v + 1
            if top == 0 or (slope[top - 1] > 0.0 and cam_h + slope[top - 1] * z_e > h_max):
                return n_walk, min(ray.t_x, ray.t_y)  # no open row left below the tallest obstacle
        ray = ray_next(ray)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _render_kernel(
    height: np.ndarray,
    cell_m: float,
    origin_x: float,
    origin_y: float,
    poses: np.ndarray,
    xu_cols: np.ndarray,
    slope: np.ndarray,
    floor_depth: np.ndarray,
    z_max: np.ndarray,
    cam_h: float,
    max_range: float,
    h_max: float,
    out: np.ndarray,
) -> None:
    """Fill ``out`` (R, H, W). Tables per camera: ``xu_cols`` (W,) tangent of each column,
    ``slope`` (H,) height gained per metre of z per row (decreasing), ``floor_depth`` (W, H) z of
    the floor point of each pixel (0 if out of range or looking up), ``z_max`` (W, H) largest z in
    range per pixel."""
    s_max = max_range / cell_m  # horizontal distance never exceeds the Euclidean one
    walk_x, walk_y, walk_t = walk_buffers(s_max)
    for r in range(poses.shape[0]):
        px, py, cos_y, sin_y = camera_in_grid(poses, r, origin_x, origin_y, cell_m)
        for u in range(out.shape[2]):
            dx, dy, norm = column_ray(cos_y, sin_y, xu_cols[u])
            render_column(
                height, cell_m, px, py, dx, dy, norm, slope, floor_depth, z_max, cam_h, s_max, h_max, out, r, u,
                walk_x, walk_y, walk_t,
            )  # fmt: skip


def render_depth(
    height_m: np.ndarray,
    cell_m: float,
    origin_xy: tuple[float, float],
    poses: np.ndarray,
    camera: CameraConfig,
    out: np.ndarray | None = None,
    h_max: float | None = None,
) -> np.ndarray:
    """Render depth images for robots at ``poses`` (R, 3) = (x, y, yaw) in map-frame metres/radians.

    Returns (R, H, W) float32 z-depth in metres, 0 where nothing is seen within range.
    ``h_max`` (the tallest obstacle, metres) is computed from ``height_m`` when not given.
    """
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    if out is None:
        out = np.empty((poses.shape[0], camera.height_px, camera.width_px), dtype=np.float32)
    tables = camera_tables(camera)
    _render_kernel(
        height_m,
        float(cell_m),
        float(origin_xy[0]),
        float(origin_xy[1]),
        poses,
        tables.xu,
        tables.slope,
        tables.floor_depth,
        tables.z_max,
        camera.mount_height_m,
        camera.max_range_m,
        float(height_m.max()) if h_max is None else h_max,
        out,
    )
    return out


class CameraTables(NamedTuple):
    """Per-pixel geometry of a level pinhole camera, shared by the renderer and the mapper."""

    xu: np.ndarray
    """(W,) horizontal tangent of each column (right of the optical axis per metre of z)."""
    slope: np.ndarray
    """(H,) height gained per metre of z along each row (row 0 looks up; decreasing)."""
    floor_depth: np.ndarray
    """(W, H) z-depth at which each pixel's ray meets the floor; 0 if never or out of range."""
    z_max: np.ndarray
    """(W, H) largest z-depth whose Euclidean distance is within range, per pixel."""


@functools.lru_cache(maxsize=16)
def camera_tables(camera: CameraConfig) -> CameraTables:
    """Precomputed pixel geometry of ``camera`` (cached; the config is frozen)."""
    xu = (np.arange(camera.width_px, dtype=np.float64) - camera.cx) / camera.fx
    slope = -(np.arange(camera.height_px, dtype=np.float64) - camera.cy) / camera.fy
    stretch = np.sqrt(1.0 + xu[:, None] ** 2 + slope[None, :] ** 2)  # Euclidean metres per metre of z
    z_max = camera.max_range_m / stretch
    with np.errstate(divide="ignore"):
        z_floor = np.where(slope < 0, camera.mount_height_m / -np.minimum(slope, -1e-300), np.inf)
    floor_depth = np.where(z_floor[None, :] <= z_max, z_floor[None, :], 0.0)
    for table in (xu, slope, floor_depth, z_max):
        table.setflags(write=False)
    return CameraTables(xu, slope, np.ascontiguousarray(floor_depth), np.ascontiguousarray(z_max))
