"""Pipeline stage "depth": a level pinhole depth camera rendered from the 2.5D scene.

The scene is a height field: every obstacle cell is a vertical prism from the floor (height 0)
up to ``height_m[iy, ix]``; free cells are bare floor. Each robot carries a camera at
``mount_height_m`` looking along its heading, with intrinsics from :class:`CameraConfig`
(square pixels, principal point at the image centre).

For a level pinhole camera all pixels of one image column lie in one vertical plane, so the
renderer walks one exact grid traversal (Amanatides & Woo 1987) per column and, at each obstacle
face, resolves the rows whose rays meet the face below its top before they meet the floor.
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

from .config import CameraConfig

GRAZE = 1e-4
"""Cells: a ray crossing less than this much of an obstacle cell's corner does not hit it (the
rendering rule; any other ray caster that must agree with the depth images uses it too)."""


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
    n_rows = out.shape[1]
    n_cols = out.shape[2]
    gh = height.shape[0]
    gw = height.shape[1]
    hit = np.empty(n_rows)  # z of the obstacle face each row meets, or -1
    s_max = max_range / cell_m  # horizontal distance never exceeds the Euclidean one
    for r in range(poses.shape[0]):
        px = (poses[r, 0] - origin_x) / cell_m
        py = (poses[r, 1] - origin_y) / cell_m
        cos_y = math.cos(poses[r, 2])
        sin_y = math.sin(poses[r, 2])
        for u in range(n_cols):
            xu = xu_cols[u]
            # Horizontal ray direction (forward + xu * right), right = (sin, -cos).
            dx = cos_y + xu * sin_y
            dy = sin_y - xu * cos_y
            norm = math.sqrt(dx * dx + dy * dy)  # horizontal metres per metre of z
            dx /= norm
            dy /= norm
            for v in range(n_rows):
                hit[v] = -1.0
            # Rows [0, top) are still open; rows below the floor boundary met the floor first.
            top = n_rows
            ix = int(math.floor(px))
            iy = int(math.floor(py))
            step_x = 1 if dx > 0 else -1
            step_y = 1 if dy > 0 else -1
            t_dx = abs(1.0 / dx) if dx != 0.0 else np.inf
            t_dy = abs(1.0 / dy) if dy != 0.0 else np.inf
            if dx > 0:
                t_x = (ix + 1 - px) * t_dx
            elif dx < 0:
                t_x = (px - ix) * t_dx
            else:
                t_x = np.inf
            if dy > 0:
                t_y = (iy + 1 - py) * t_dy
            elif dy < 0:
                t_y = (py - iy) * t_dy
            else:
                t_y = np.inf
            t_enter = 0.0
            while t_enter <= s_max:
                if ix < 0 or iy < 0 or ix >= gw or iy >= gh:
                    break
                h = height[iy, ix]
                # a ray that only grazes a corner (less than GRAZE cells inside) passes by, so every
                # reported hit lies well inside its cell's face for the mapper
                if h > 0.0 and t_enter > 0.0 and min(t_x, t_y) - t_enter >= GRAZE:
                    z_e = t_enter * cell_m / norm
                    # lowest row still above the floor at z_e: slope > -cam_h / z_e
                    floor_slope = -cam_h / z_e
                    top_slope = (h - cam_h) / z_e
                    bot = top - 1
                    while bot >= 0 and slope[bot] <= floor_slope:
                        bot -= 1
                    v = bot
                    while v >= 0 and slope[v] <= top_slope:
                        if z_e <= z_max[u, v]:
                            hit[v] = z_e
                        else:
                            hit[v] = 0.0
                        v -= 1
                    if v < bot:  # rows v+1 .. bot were hit; rows bot+1 .. top-1 see the floor
                        top = v + 1
                    if top == 0 or (slope[top - 1] > 0.0 and cam_h + slope[top - 1] * z_e > h_max):
                        break  # no open row left below the tallest obstacle
                if t_x < t_y:
                    t_enter = t_x
                    t_x += t_dx
                    ix += step_x
                else:
                    t_enter = t_y
                    t_y += t_dy
                    iy += step_y
            for v in range(n_rows):
                out[r, v, u] = hit[v] if hit[v] >= 0.0 else floor_depth[u, v]


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
