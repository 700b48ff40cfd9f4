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

import math

import numba
import numpy as np

from .config import CameraConfig


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _render_kernel(
    height: np.ndarray,
    cell_m: float,
    origin_x: float,
    origin_y: float,
    poses: np.ndarray,
    fx: float,
    cx: float,
    fy: float,
    cy: float,
    cam_h: float,
    max_range: float,
    h_max: float,
    out: np.ndarray,
) -> None:
    n_rows = out.shape[1]
    n_cols = out.shape[2]
    gh = height.shape[0]
    gw = height.shape[1]
    slope = np.empty(n_rows)  # height gained per metre of z, per row (row 0 looks up)
    z_floor = np.empty(n_rows)  # z at which the row's ray meets the floor (inf if never)
    for v in range(n_rows):
        slope[v] = -(v - cy) / fy
        z_floor[v] = cam_h / -slope[v] if slope[v] < 0.0 else np.inf
    done = np.empty(n_rows, dtype=np.bool_)
    for r in range(poses.shape[0]):
        px = (poses[r, 0] - origin_x) / cell_m
        py = (poses[r, 1] - origin_y) / cell_m
        cos_y = math.cos(poses[r, 2])
        sin_y = math.sin(poses[r, 2])
        for u in range(n_cols):
            xu = (u - cx) / fx  # right of the optical axis per metre of z
            # Horizontal ray direction (forward + xu * right), right = (sin, -cos).
            dx = cos_y + xu * sin_y
            dy = sin_y - xu * cos_y
            norm = math.sqrt(dx * dx + dy * dy)  # horizontal metres per metre of z
            dx /= norm
            dy /= norm
            for v in range(n_rows):
                done[v] = False
                out[r, v, u] = 0.0
            n_done = 0
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
            s_max = max_range / cell_m  # horizontal distance never exceeds the Euclidean one
            t_enter = 0.0
            while t_enter <= s_max and n_done < n_rows:
                if ix < 0 or iy < 0 or ix >= gw or iy >= gh:
                    break
                h = height[iy, ix]
                if h > 0.0:
                    z_e = t_enter * cell_m / norm
                    all_above = True
                    for v in range(n_rows):
                        if done[v]:
                            continue
                        if z_floor[v] <= z_e:
                            continue  # this row met the floor first (resolved below)
                        y_at = cam_h + slope[v] * z_e
                        if y_at <= h:
                            done[v] = True
                            n_done += 1
                            dist = z_e * math.sqrt(1.0 + xu * xu + slope[v] * slope[v])
                            if dist <= max_range:
                                out[r, v, u] = z_e
                        elif y_at <= h_max:
                            all_above = False
                        elif slope[v] <= 0.0:
                            all_above = False
                    if all_above:
                        break  # every open row is climbing above the tallest obstacle
                if t_x < t_y:
                    t_enter = t_x
                    t_x += t_dx
                    ix += step_x
                else:
                    t_enter = t_y
                    t_y += t_dy
                    iy += step_y
            # Rows still open met the floor before any obstacle: the traversal only stops early
            # (leaving the grid, passing the range, or all open rows climbing) once no open row
            # can still be blocked short of its floor point.
            for v in range(n_rows):
                if not done[v] and z_floor[v] < np.inf:
                    dist = z_floor[v] * math.sqrt(1.0 + xu * xu + slope[v] * slope[v])
                    if dist <= max_range:
                        out[r, v, u] = z_floor[v]


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
    _render_kernel(
        height_m,
        float(cell_m),
        float(origin_xy[0]),
        float(origin_xy[1]),
        poses,
        camera.fx,
        camera.cx,
        camera.fy,
        camera.cy,
        camera.mount_height_m,
        camera.max_range_m,
        float(height_m.max()) if h_max is None else h_max,
        out,
    )
    return out
