"""Log-odds occupancy for the reconstruction mapper (``mapping.occupancy = "log_odds"``,
:class:`~areasearch.config.MappingConfig`): a probabilistic occupancy grid that clears a cell seen free
again, where the sticky rule of :mod:`areasearch.sim.mapper` keeps every outlier of a noisy depth camera
as an obstacle for good.

Why: with range noise (``noise.depth``) the points of a wall face spread along each pixel's ray, and those
that fall short land in the free cells before the wall; sticky occupancy keeps every one of them, the walls
grow into the rooms by a few cells, doorways close and the team stops exploring (measured in
docs/environments.md, "Occupancy under depth noise"). A real robot's mapper keeps, per cell, the log-odds
of being occupied and adds each scan's evidence (OctoMap: Hornung et al., Autonomous Robots 2013).

**Evidence of one frame** (one robot's depth image), per cell, counted over the frame's pixels: a pixel
whose point is an obstacle point (height in (``floor_tolerance_m``, ``obstacle_top_m``]) is a *hit* in
the point's cell; a floor point is a *miss* in its cell; and every point's ray (floor or obstacle) is a
miss in each cell it crosses before its own (the camera is level, so all pixels of a column share one
horizontal ray; the walk is :mod:`areasearch.sim.raycast`'s). Points above the robot and pixels without a
return give nothing, as in the sticky mapper.

**The frame's vote** per cell is the majority of those counts: hits > misses votes *hit* (log-odds +=
``l_hit``), misses > hits votes *miss* (+= ``l_miss``), a tie casts no vote. Why a majority rather than
OctoMap's "hit wins" (a cell both hit and missed in one scan counts as a hit): under range noise a wall
column's points scatter about the face; the short ones fall in the cells before the wall, but more rays
of the same column pass through those cells to the points behind, so the majority votes them free, while
the wall's own cell holds the points that are not short and is crossed only by the few that overshoot it:
a wall one cell thick stays occupied (at the camera's 3.2 m range with ``noise.depth`` 0.02 about 28 %
of a column's wall points fall in the face cell and 22 % beyond it; the log-odds' asymmetry, 0.85 up
against 0.41 down, keeps a cell occupied that is voted hit in a third of the frames). "Hit wins" would
keep every short point's cell as an obstacle in the frame that made it, and the walls would grow again.
A single outlier floor point (height above the floor tolerance) is a hit of one pixel; it is outvoted where
other rays cross its cell, and otherwise cleared by the next frames that see the cell free (three miss
votes undo one hit vote).

Then ``l`` is clamped to [``l_min``, ``l_max``]; a cell is **occupied while its log-odds is positive**;
``occupied_at`` is set to the integration's stamp when a cell turns occupied (the action planner re-plans
round obstacles newer than its path) and keeps that stamp when the cell clears. **Explored** stays sticky:
every cell the frame gave evidence on (a point in it or a ray through it) is explored from then on.

Caveat (as of every 2D occupancy grid cleared by ray-tracing, e.g. ROS costmap_2d's obstacle layer): a
ray that passes *over* a low obstacle to a point behind it counts as a miss there. The bundled maps hold
walls only (2.5 m, taller than any ray), so it does not arise in them.

:func:`integrate_log_odds` is the kernel (numba); :func:`integrate_log_odds_reference` the same rule in
plain Python / NumPy, for the tests.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .depth import camera_in_grid, column_ray
from .raycast import ray_in_grid, ray_next, ray_start

EPS_CELLS = 5e-5
"""Cells an obstacle point is binned behind its face along the ray (the sticky mapper's rule)."""


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _column_points(
    depth: np.ndarray, r: int, u: int, slope: np.ndarray, cam_h: float, floor_tol: float, obstacle_top: float,
    scale: float, s_pts: np.ndarray, kind: np.ndarray,
) -> int:  # fmt: skip
    """Column ``u`` of image ``r``'s points as distances along the ray (cells; an obstacle point
    ``EPS_CELLS`` behind its face) in ``s_pts`` and ``kind`` (1 obstacle, 0 floor), sorted by distance;
    returns how many."""
    n = 0
    for v in range(depth.shape[1]):
        z = depth[r, v, u]
        if not (z > 0.0) or not math.isfinite(z):
            continue
        height = cam_h + slope[v] * z
        if height <= floor_tol:
            s, k = z * scale, 0
        elif height <= obstacle_top:
            s, k = z * scale + EPS_CELLS, 1
        else:
            continue
        j = n  # insertion sort: at most H points
        while j > 0 and s_pts[j - 1] > s:
            s_pts[j] = s_pts[j - 1]
            kind[j] = kind[j - 1]
            j -= 1
        s_pts[j] = s
        kind[j] = k
        n += 1
    return n


@numba.njit(cache=True, nogil=True, error_model="numpy")
def integrate_log_odds(
    depth: np.ndarray,
    poses: np.ndarray,
    xu_cols: np.ndarray,
    slope: np.ndarray,
    cam_h: float,
    floor_tol: float,
    obstacle_top: float,
    cell_m: float,
    origin_x: float,
    origin_y: float,
    params: np.ndarray,
    log_odds: np.ndarray,
    explored: np.ndarray,
    occupied: np.ndarray,
    occupied_at: np.ndarray,
    stamp: int,
    new_cells: np.ndarray,
    hits: np.ndarray,
    misses: np.ndarray,
    touched: np.ndarray,
) -> int:
    """Fuse depth images (R, H, W) taken at ``poses`` (R, 3) into the log-odds map, one frame after
    another (the module's rule); ``params`` = (l_hit, l_miss, l_min, l_max). ``hits``, ``misses`` (H, W)
    int32, zero on entry and on return, and ``touched`` (H * W,) int64 are scratch. Returns the number of
    newly explored cells written to ``new_cells`` (flat indices)."""
    gh, gw = explored.shape
    l_hit, l_miss, l_min, l_max = params[0], params[1], params[2], params[3]
    s_pts = np.empty(depth.shape[1])
    kind = np.empty(depth.shape[1], dtype=np.int8)
    n_new = 0
    for r in range(depth.shape[0]):
        px, py, cos_y, sin_y = camera_in_grid(poses, r, origin_x, origin_y, cell_m)
        n_touched = 0
        for u in range(depth.shape[2]):
            dx, dy, norm = column_ray(cos_y, sin_y, xu_cols[u])
            n = _column_points(depth, r, u, slope, cam_h, floor_tol, obstacle_top, norm / cell_m, s_pts, kind)
            k = 0
            ray = ray_start(px, py, dx, dy)
            while k < n and ray_in_grid(ray, gh, gw):
                t_exit = min(ray.t_x, ray.t_y)
                h = 0
                m = 0
                while k < n and s_pts[k] < t_exit:  # the points in this cell
                    if kind[k] == 1:
                        h += 1
                    else:
                        m += 1
                    k += 1
                m += n - k  # the rays of the points beyond pass through it
                iy, ix = ray.iy, ray.ix
                if hits[iy, ix] == 0 and misses[iy, ix] == 0:
                    touched[n_touched] = iy * gw + ix
                    n_touched += 1
                hits[iy, ix] += h
                misses[iy, ix] += m
                ray = ray_next(ray)
        for i in range(n_touched):
            c = touched[i]
            iy = c // gw
            ix = c - iy * gw
            h = hits[iy, ix]
            m = misses[iy, ix]
            hits[iy, ix] = 0
            misses[iy, ix] = 0
            if not explored[iy, ix]:
                explored[iy, ix] = True
                new_cells[n_new] = c
                n_new += 1
            if h == m:
                continue
            value = log_odds[iy, ix] + (l_hit if h > m else l_miss)
            log_odds[iy, ix] = min(max(value, l_min), l_max)
            now = log_odds[iy, ix] > 0.0
            if now and not occupied[iy, ix]:
                occupied_at[iy, ix] = stamp
            occupied[iy, ix] = now
    return n_new


def integrate_log_odds_reference(
    depth: np.ndarray,
    poses: np.ndarray,
    xu_cols: np.ndarray,
    slope: np.ndarray,
    cam_h: float,
    floor_tol: float,
    obstacle_top: float,
    cell_m: float,
    origin_xy: tuple[float, float],
    params: tuple[float, float, float, float],
    log_odds: np.ndarray,
    explored: np.ndarray,
    occupied: np.ndarray,
    occupied_at: np.ndarray,
    stamp: int,
) -> np.ndarray:
    """:func:`integrate_log_odds` in plain Python / NumPy (the arrays updated in place); returns the flat
    indices of the newly explored cells, sorted. Each column: its cells by the ray walk with their exit
    distances, each point placed in a cell by a search among the exits, the rays beyond a cell counted by
    a search among the sorted points."""
    gh, gw = explored.shape
    walk_start, walk_next = ray_start.py_func, ray_next.py_func
    new: list[int] = []
    for r in range(depth.shape[0]):
        x, y, yaw = (float(v) for v in poses[r])
        px, py = (x - origin_xy[0]) / cell_m, (y - origin_xy[1]) / cell_m
        hits = np.zeros(gh * gw, dtype=np.int64)
        misses = np.zeros(gh * gw, dtype=np.int64)
        seen = np.zeros(gh * gw, dtype=bool)
        for u in range(depth.shape[2]):
            dx, dy, norm = column_ray.py_func(math.cos(yaw), math.sin(yaw), float(xu_cols[u]))
            z = depth[r, :, u].astype(np.float64)
            ok = (z > 0) & np.isfinite(z)
            height = cam_h + slope * np.where(ok, z, 0.0)
            floor = ok & (height <= floor_tol)
            obstacle = ok & (height > floor_tol) & (height <= obstacle_top)
            s = np.concatenate([z[floor] * (norm / cell_m), z[obstacle] * (norm / cell_m) + EPS_CELLS])
            is_hit = np.concatenate([np.zeros(int(floor.sum()), bool), np.ones(int(obstacle.sum()), bool)])
            if len(s) == 0:
                continue
            cells: list[int] = []
            exits: list[float] = []
            ray = walk_start(px, py, dx, dy)
            while ray_in_grid.py_func(ray, gh, gw) and (not exits or exits[-1] <= s.max()):
                cells.append(ray.iy * gw + ray.ix)
                exits.append(min(ray.t_x, ray.t_y))
                ray = walk_next(ray)
            cells_a, exits_a = np.array(cells, dtype=np.int64), np.array(exits)
            where = np.searchsorted(exits_a, s, side="right")  # the cell whose exit is beyond the point
            inside = where < len(cells_a)
            np.add.at(hits, cells_a[where[inside & is_hit]], 1)
            np.add.at(misses, cells_a[where[inside & ~is_hit]], 1)
            beyond = len(s) - np.searchsorted(np.sort(s), exits_a, side="left")  # points at or past the exit
            np.add.at(misses, cells_a, beyond)
            seen[cells_a] = True
        idx = np.flatnonzero(seen)
        fresh = idx[~explored.flat[idx]]
        explored.flat[fresh] = True
        new.extend(fresh.tolist())
        h, m = hits[idx], misses[idx]
        vote = idx[h != m]
        step = np.where(h[h != m] > m[h != m], params[0], params[1])
        value = np.clip(log_odds.flat[vote].astype(np.float64) + step, params[2], params[3])
        log_odds.flat[vote] = value.astype(np.float32)
        now = log_odds.flat[vote] > 0
        turned = vote[now & ~occupied.flat[vote]]
        occupied_at.flat[turned] = stamp
        occupied.flat[vote] = now
    return np.sort(np.array(new, dtype=np.int64))


def merge_log_odds(log_odds: list[np.ndarray]) -> np.ndarray:
    """The merged log-odds of a group's maps: the members' mean, per cell (float32). Why the mean: it
    keeps each map's evidence in proportion (a cell one member saw free many times and another saw once
    as a hit is free), never counts one frame twice (a sum would, merged every step), and is the same for
    every member, so the group agrees on one map."""
    return np.asarray(np.mean(np.stack(log_odds), axis=0, dtype=np.float64), dtype=np.float32)
