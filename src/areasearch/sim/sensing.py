"""One sensing step of the world in numba: every robot's depth image, fused into the team's map,
then the targets discovered and covered.

:func:`sense_kernel` is what :meth:`areasearch.sim.world.World.step` calls after the moves:
:func:`see_kernel` renders each robot's depth image (:mod:`areasearch.sim.depth`) and fuses it into
the mapper's grids as :meth:`areasearch.sim.mapper.Mapper.integrate` does, in one pass per image
column (it writes the mapper's column update out rather than calling it, see there: inlined, the
call costs a few per cent of a step); :func:`targets_kernel` discovers targets on newly explored
cells and covers discovered targets by the configured protocol's rule. ``tests/sim/test_world.py``
checks the map against the plain ``render_depth`` followed by ``Mapper.integrate``.

Units: metres and radians; cells (iy, ix) of the scene's grid, flat indices ``iy * W + ix``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .depth import camera_in_grid, column_ray, render_column, walk_buffers
from .mapper import carve_ray, mark_explored


@numba.njit(cache=True, nogil=True, error_model="numpy")
def targets_kernel(
    new_cells: np.ndarray,
    free_flat: np.ndarray,
    target_id_flat: np.ndarray,
    target_cells: np.ndarray,
    targets_xy: np.ndarray,
    poses: np.ndarray,
    previous_xy: np.ndarray,
    cover_r2: float,
    swept: bool,
    step: int,
    discovered: np.ndarray,
    discovered_at: np.ndarray,
    covered: np.ndarray,
    covered_at: np.ndarray,
    map_targets: np.ndarray,
    counts: np.ndarray,
) -> None:
    """Count newly explored free cells, discover targets on them, cover discovered targets a robot
    comes within ``sqrt(cover_r2)`` of: with ``swept``, anywhere on the segment its centre swept this
    step (``previous_xy`` to ``poses``), else at the end of the step. ``counts`` (3,) accumulates
    [explored free cells, discovered, covered]."""
    for c in new_cells:
        if free_flat[c]:
            counts[0] += 1
        k = target_id_flat[c]
        if k >= 0 and not discovered[k]:
            discovered[k] = True
            discovered_at[k] = step
            counts[1] += 1
            map_targets[target_cells[k, 0], target_cells[k, 1]] = True
    if counts[1] == counts[2]:
        return
    n = poses.shape[0]
    reach2 = np.zeros(n)  # swept: a target farther than this from the end of the segment is not near it
    if swept:
        cover_r = math.sqrt(cover_r2)
        for r in range(n):
            length = math.hypot(poses[r, 0] - previous_xy[r, 0], poses[r, 1] - previous_xy[r, 1])
            if length > 0.0:
                reach2[r] = (length + cover_r) ** 2
    for k in range(discovered.shape[0]):
        if discovered[k] and not covered[k]:
            for r in range(n):
                ddx = targets_xy[k, 0] - poses[r, 0]
                ddy = targets_xy[k, 1] - poses[r, 1]
                d2 = ddx * ddx + ddy * ddy
                if d2 > cover_r2 and d2 <= reach2[r]:
                    # near the swept segment: from its nearest point (previous -> now) to the target
                    sx = poses[r, 0] - previous_xy[r, 0]
                    sy = poses[r, 1] - previous_xy[r, 1]
                    ddx = targets_xy[k, 0] - previous_xy[r, 0]
                    ddy = targets_xy[k, 1] - previous_xy[r, 1]
                    t = min(1.0, max(0.0, (ddx * sx + ddy * sy) / (sx * sx + sy * sy)))
                    ddx -= t * sx
                    ddy -= t * sy
                    d2 = ddx * ddx + ddy * ddy
                if d2 <= cover_r2:
                    covered[k] = True
                    covered_at[k] = step
                    counts[2] += 1
                    map_targets[target_cells[k, 0], target_cells[k, 1]] = False
                    break


@numba.njit(cache=True, nogil=True, error_model="numpy")
def see_kernel(
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
    floor_tol: float,
    obstacle_top: float,
    explored: np.ndarray,
    occupied: np.ndarray,
    occupied_at: np.ndarray,
    stamp: int,
    new_cells: np.ndarray,
    sensed: np.ndarray,
) -> int:
    """Render the depth images into ``out`` (R, H, W) and fuse them into the map, column by column;
    returns the number of newly explored cells written to ``new_cells``.

    ``sensed`` (R, 3) holds the pose each robot last sensed from (NaN: never) and is updated. A robot
    whose pose is exactly that one is skipped: the scene is static and robots do not appear in each
    other's images, so it would render the image ``out`` already holds, and the map, which only ever
    gains explored and occupied cells, already holds everything that image shows (about half the
    robot-steps of an episode are such: robots that arrived, wait, or were blocked).

    Per image column it runs the renderer's :func:`~areasearch.sim.depth.render_column` and the mapper's
    work (:func:`~areasearch.sim.mapper.fuse_column`) on its float32 output, as ``render_depth`` followed by
    ``Mapper.integrate`` would; both walk the same horizontal ray with the same floating-point steps
    (:mod:`areasearch.sim.raycast`), so the mapper's carve along the ray reuses the cells the renderer's
    walk recorded instead of walking the ray a second time (:func:`~areasearch.sim.mapper.carve_ray` walks
    on its own only past the renderer's last cell, rarely)."""
    gh = height.shape[0]
    gw = height.shape[1]
    s_max = max_range / cell_m
    walk_x, walk_y, walk_t = walk_buffers(s_max)
    floor_s = np.empty(out.shape[1])
    n_new = 0
    for r in range(poses.shape[0]):
        if poses[r, 0] == sensed[r, 0] and poses[r, 1] == sensed[r, 1] and poses[r, 2] == sensed[r, 2]:
            continue
        sensed[r, 0], sensed[r, 1], sensed[r, 2] = poses[r, 0], poses[r, 1], poses[r, 2]
        px, py, cos_y, sin_y = camera_in_grid(poses, r, origin_x, origin_y, cell_m)
        for u in range(out.shape[2]):
            dx, dy, norm = column_ray(cos_y, sin_y, xu_cols[u])
            n_walk, t_next = render_column(
                height, cell_m, px, py, dx, dy, norm, slope, floor_depth, z_max, cam_h, s_max, h_max, out, r, u,
                walk_x, walk_y, walk_t,
            )  # fmt: skip
            # ---- map: mapper.fuse_column's work, written out here because inlined it costs a few per cent
            # of World.step (numba keeps counting references to its seven array arguments every column)
            scale = norm / cell_m
            eps = 5e-5
            s_obstacle = np.inf
            s_floor = 0.0
            n_floor = 0
            last_z = -1.0
            for v in range(out.shape[1]):
                z = float(out[r, v, u])
                if not (z > 0.0):
                    continue
                z_height = cam_h + slope[v] * z
                if z_height <= floor_tol:
                    s = z * scale
                    floor_s[n_floor] = s
                    n_floor += 1
                    if s > s_floor:
                        s_floor = s
                elif z_height <= obstacle_top and z != last_z:
                    last_z = z
                    s = z * scale
                    cy = int(math.floor(py + dy * (s + eps)))
                    cx = int(math.floor(px + dx * (s + eps)))
                    if 0 <= cy < gh and 0 <= cx < gw:
                        if not occupied[cy, cx]:
                            occupied[cy, cx] = True
                            occupied_at[cy, cx] = stamp
                        n_new = mark_explored(cy, cx, explored, new_cells, n_new)
                    if s < s_obstacle:
                        s_obstacle = s
            s_carve = s_obstacle + eps if s_obstacle < np.inf else s_floor
            for k in range(n_floor):
                s = floor_s[k]
                if s > s_carve:
                    n_new = mark_explored(
                        int(math.floor(py + dy * s)), int(math.floor(px + dx * s)), explored, new_cells, n_new
                    )
            if s_carve <= 0.0:
                continue
            k = 0
            while k < n_walk and walk_t[k] <= s_carve:
                cy, cx = walk_y[k], walk_x[k]
                if not explored[cy, cx]:
                    explored[cy, cx] = True
                    new_cells[n_new] = cy * gw + cx
                    n_new += 1
                k += 1
            if k == n_walk and t_next <= s_carve:
                # the carve goes past the renderer's walk: walk the ray on, as the mapper does
                n_new = carve_ray(px, py, dx, dy, s_carve, explored, new_cells, n_new)
    return n_new


@numba.njit(cache=True, nogil=True, error_model="numpy")
def sense_kernel(
    height: np.ndarray,
    cell_m: float,
    origin_x: float,
    origin_y: float,
    poses: np.ndarray,
    xu: np.ndarray,
    slope: np.ndarray,
    floor_depth: np.ndarray,
    z_max: np.ndarray,
    cam_h: float,
    max_range: float,
    h_max: float,
    depth: np.ndarray,
    floor_tol: float,
    obstacle_top: float,
    explored: np.ndarray,
    occupied: np.ndarray,
    occupied_at: np.ndarray,
    stamp: int,
    new_cells: np.ndarray,
    free_flat: np.ndarray,
    target_id_flat: np.ndarray,
    target_cells: np.ndarray,
    targets_xy: np.ndarray,
    previous_xy: np.ndarray,
    cover_r2: float,
    swept: bool,
    step: int,
    discovered: np.ndarray,
    discovered_at: np.ndarray,
    covered: np.ndarray,
    covered_at: np.ndarray,
    map_targets: np.ndarray,
    counts: np.ndarray,
    sensed: np.ndarray,
) -> None:
    """One sensing step in one call: render every robot's depth image (:mod:`areasearch.sim.depth`) and
    fuse the images into the mapper's grids (:mod:`areasearch.sim.mapper`, as ``Mapper.integrate``
    does) with :func:`see_kernel` (robots that have not moved since they last sensed skipped, see
    there), then discover and cover targets (:func:`targets_kernel`, every robot)."""
    n_new = see_kernel(
        height, cell_m, origin_x, origin_y, poses, xu, slope, floor_depth, z_max, cam_h, max_range, h_max, depth,
        floor_tol, obstacle_top, explored, occupied, occupied_at, stamp, new_cells, sensed,
    )  # fmt: skip
    targets_kernel(
        new_cells[:n_new], free_flat, target_id_flat, target_cells, targets_xy, poses, previous_xy, cover_r2, swept,
        step, discovered, discovered_at, covered, covered_at, map_targets, counts,
    )  # fmt: skip
