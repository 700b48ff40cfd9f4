"""One decision on your own map: the planners' observation built from the map alone (:func:`build_decision`).

The same pipeline stages as the simulator's decisions: the robots' poses and the targets checked
(each error naming the input at fault), the floor the robots stand on made free (unknown cells under
a footprint, a small unknown pocket a robot stands in), each robot's planning cell (its own, or the
nearest one with the planner's clearance), the candidates
(:func:`areasearch.planning.candidates.extract_candidates`: frontier and target nodes with FMM
distances) and the observation of :class:`areasearch.envs.goal.AreaSearchEnv`
(:func:`areasearch.envs.observation.build_observation`). :mod:`.assign` hands it to a planner.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from ..config import MAX_ROBOTS, SearchConfig
from ..envs.observation import build_observation
from ..errors import ConfigError, MapError
from ..inputs import is_real, real_number, short
from ..planning.candidates import Candidates, extract_candidates, search_candidate_params
from ..planning.grid import clearance_threshold_m, disc_offsets, planning_grid
from .grid import OccupancyMap


def _leaves(value: Any) -> list[Any]:
    """The items of nested lists and tuples (NumPy arrays are left whole: their dtype says what they hold)."""
    if not isinstance(value, (list, tuple)):
        return [value] if not isinstance(value, np.ndarray) else []
    return [leaf for item in value for leaf in _leaves(item)]


def finite_rows(name: str, value: Any, width: int, what: str) -> np.ndarray:
    """``value`` as an (N, width) float64 array of finite numbers, or ConfigError naming ``name``: real
    numbers only (Python's, NumPy's of any width: ``np.float32`` poses work), never text (``"1.0"``),
    booleans or complex numbers, which a cast to float would read or fail on."""
    wrong = [v for v in _leaves(value) if not is_real(v)][:1]
    if wrong:  # before NumPy reads True as 1.0 in a list of floats
        raise ConfigError(
            f"{name} must be an (N, {width}) array of {what} (real numbers), got {short(wrong[0])} in {short(value)}"
        )
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError):  # ragged nesting
        raise ConfigError(f"{name} must be an (N, {width}) array of {what}, got {short(value)}") from None
    kind = raw.dtype.kind
    arr: np.ndarray[Any, np.dtype[np.float64]]
    if kind == "O":  # Python ints beyond int64, NumPy scalars of mixed kinds, anything else
        flat = raw.reshape(-1)
        odd = [v for v in flat if not is_real(v)][:1]
        if odd:
            raise ConfigError(
                f"{name} must be an (N, {width}) array of {what} (real numbers), got {short(odd[0])} in {short(value)}"
            )
        arr = np.array([real_number(name, v) for v in flat], dtype=np.float64).reshape(raw.shape)
    elif kind in "iuf":
        arr = raw.astype(np.float64)
    else:  # bool, complex, text, bytes, dates
        raise ConfigError(
            f"{name} must be an (N, {width}) array of {what} (real numbers), got {raw.dtype.name} values: "
            f"{short(value)}"
        )
    if arr.size == 0:
        return np.zeros((0, width))
    if arr.ndim == 1 and arr.shape[0] == width:
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != width:
        raise ConfigError(f"{name} must be an (N, {width}) array of {what}, got shape {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise ConfigError(f"{name}[{i}] must hold finite numbers, got {arr[i].tolist()} (entry {j} is {arr[i, j]})")
    return arr


def normalise_yaw(yaw: np.ndarray) -> np.ndarray:
    """Yaw angles (any finite radians) as the same directions in [-pi, pi)."""
    return np.remainder(np.asarray(yaw, dtype=np.float64) + math.pi, 2 * math.pi) - math.pi


def _label(r: int, names: Sequence[str] | None) -> str:
    return f"robot {short(names[r], 40)}" if names is not None and r < len(names) else f"robot {r}"


def _robot_cells(grid: OccupancyMap, poses: np.ndarray, radius_m: float, names: Sequence[str] | None) -> np.ndarray:
    """(R, 2) cells of the robots (at most :data:`~areasearch.config.MAX_ROBOTS`); ConfigError for a
    robot outside the grid, on an occupied cell, or whose footprint overlaps another one's (centres
    closer than the footprint diameter)."""
    for r in map(int, np.flatnonzero(~grid.contains(poses[:, :2]))):
        x, y = poses[r, :2]
        raise ConfigError(f"{_label(r, names)} at ({x:g}, {y:g}) lies outside the map ({grid.bounds_text()})")
    cells = grid.world_to_cell(poses[:, :2])
    for r in range(len(poses)):
        if grid.occupied[cells[r, 0], cells[r, 1]]:
            x, y = poses[r, :2]
            raise ConfigError(f"{_label(r, names)} at ({x:g}, {y:g}) stands on an occupied cell of the map (in a wall)")
    if len(poses) > 1:
        gap = np.hypot(*(poses[:, None, :2] - poses[None, :, :2]).transpose(2, 0, 1))  # (R, R) metres
        gap[np.diag_indices(len(poses))] = np.inf
        if gap.min() < 2 * radius_m:
            a, b = sorted(int(v) for v in np.unravel_index(int(np.argmin(gap)), gap.shape))
            raise ConfigError(
                f"{_label(a, names)} and {_label(b, names)} overlap: centres {gap[a, b]:.3f} m apart, "
                f"less than the footprint diameter {2 * radius_m:g} m (radius {radius_m:g} m)"
            )
    return cells


POCKET_M2 = 1.0
"""Largest unknown pocket around a robot, enclosed by known cells, that is taken as unseen floor, m²."""


def _footprints_free(grid: OccupancyMap, cells: np.ndarray, radius_m: float) -> np.ndarray:
    """(H, W) known-free cells, with the floor the robots stand on made free: the unknown cells under
    each robot's footprint, and the unknown pocket (at most :data:`POCKET_M2`, enclosed by known
    cells) a robot stands in, the blind spot of a sensor that cannot see the floor under itself."""
    free = grid.free.copy()
    unknown = ~grid.explored
    offsets = disc_offsets(radius_m / grid.cell_m)
    h, w = grid.shape
    reach = int(math.ceil(math.sqrt(POCKET_M2) / grid.cell_m)) + 1
    for iy, ix in cells:
        if unknown[iy, ix]:
            y0, y1, x0, x1 = max(iy - reach, 0), min(iy + reach + 1, h), max(ix - reach, 0), min(ix + reach + 1, w)
            labels, _ = ndimage.label(unknown[y0:y1, x0:x1])
            pocket = labels == labels[iy - y0, ix - x0]
            edge = pocket[0].any() or pocket[-1].any() or pocket[:, 0].any() or pocket[:, -1].any()
            if not edge and pocket.sum() * grid.cell_m**2 <= POCKET_M2:
                free[y0:y1, x0:x1] |= pocket
        disc = np.array([iy, ix]) + offsets
        disc = disc[(disc[:, 0] >= 0) & (disc[:, 0] < h) & (disc[:, 1] >= 0) & (disc[:, 1] < w)]
        inside = ~grid.occupied[disc[:, 0], disc[:, 1]]
        free[disc[inside, 0], disc[inside, 1]] = True
    return free


def _planning_cells(
    free: np.ndarray, occupied: np.ndarray, cells: np.ndarray, cell_m: float, radius_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """(R, 2) cells the robots plan from: their own cell where it has the planner's clearance from
    every occupied cell, else the nearest known-free cell that has it within that clearance (a robot
    that localisation puts too near a wall plans from just off it; the robot's own cell when there is
    none); and (R,) bool: the robot found such a cell."""
    clear = clearance_threshold_m(cell_m, radius_m) / cell_m
    offsets = disc_offsets(clear + 1.0)
    reach = int(math.ceil(2 * clear)) + 2
    h, w = free.shape
    out = cells.copy()
    found = np.zeros(len(cells), dtype=bool)
    for r, (iy, ix) in enumerate(cells):
        y0, y1, x0, x1 = max(iy - reach, 0), min(iy + reach + 1, h), max(ix - reach, 0), min(ix + reach + 1, w)
        ok = planning_grid(free[y0:y1, x0:x1], occupied[y0:y1, x0:x1], cell_m, radius_m) & free[y0:y1, x0:x1]
        for dy, dx in offsets:  # nearest first
            y, x = iy + dy - y0, ix + dx - x0
            if 0 <= y < ok.shape[0] and 0 <= x < ok.shape[1] and ok[y, x]:
                out[r] = (iy + dy, ix + dx)
                found[r] = True
                break
    return out, found


def _check_room(grid: OccupancyMap, free: np.ndarray, radius_m: float) -> None:
    if not (planning_grid(free, grid.occupied, grid.cell_m, radius_m) & free).any():
        raise MapError(
            f"{grid.source}: no free cell of the map can hold a robot of radius {radius_m:g} m "
            "(the free space is smaller than the robots)"
        )


# ---------------------------------------------------------------------------------- observation


@dataclass(frozen=True)
class Decision:
    """What one decision on a given map saw: the planner's observation and the candidates behind it."""

    obs: dict[str, np.ndarray]
    """The observation of :class:`~areasearch.envs.goal.AreaSearchEnv` (same keys, shapes, units)."""
    candidates: Candidates
    """The candidate goals (with the robots' distance fields, ``routes``), in observation order."""
    grid: OccupancyMap
    """The map as planned on (unknown cells under the robots' footprints made free)."""
    robot_cells: np.ndarray
    """(R, 2) cells the robots plan from."""


def _history(
    grid: OccupancyMap, name: str, entries: Sequence[Any] | None, robots: int, keep: int, allow_none: bool
) -> np.ndarray:
    """(H, R, 2) float32 cells of per-robot past points (newest first), -1 where a robot has none."""
    if entries is None:
        return np.full((0, robots, 2), -1.0, dtype=np.float32)
    if len(entries) != robots:
        raise ConfigError(f"{name} must hold one list per robot ({robots}), got {len(entries)}")
    rows = []
    for r, entry in enumerate(entries):
        points = [] if entry is None else list(entry)
        cells = np.full((len(points), 2), -1, dtype=np.int64)
        for k, point in enumerate(points):
            if point is None and allow_none:
                continue
            xy = finite_rows(f"{name}[{r}][{k}]", point, 2, "x, y in metres")
            if len(xy) != 1:
                raise ConfigError(f"{name}[{r}][{k}] must be one [x, y] point")
            if not grid.contains(xy)[0]:
                raise ConfigError(f"{name}[{r}][{k}] at ({xy[0, 0]:g}, {xy[0, 1]:g}) lies outside the map")
            cells[k] = grid.world_to_cell(xy[0])
        rows.append(cells[:keep])
    depth = max((len(c) for c in rows), default=0)
    out = np.full((depth, robots, 2), -1.0, dtype=np.float32)
    for r, cells in enumerate(rows):
        out[: len(cells), r] = cells
    return out


def build_decision(
    grid: OccupancyMap,
    poses: np.ndarray,
    targets: np.ndarray | None = None,
    past_positions: Sequence[Any] | None = None,
    past_goals: Sequence[Any] | None = None,
    *,
    config: SearchConfig | None = None,
    progress: float = 0.0,
    robot_names: Sequence[str] | None = None,
) -> Decision:
    """The planner's observation of one decision on a given map, as
    :class:`~areasearch.envs.goal.AreaSearchEnv` builds it from its world, here from the map alone.

    ``poses`` (R, 3) x, y, yaw (metres, radians, map frame); ``targets`` (T, 2) x, y of known
    targets to cover; ``past_positions`` / ``past_goals``: per robot, its positions and goals at past
    decisions, newest first ([x, y] points; a goal may be None). ``progress`` in [0, 1]: the share
    of the mission time spent (the learned planners read it; 0 by default); ``robot_names`` name the
    robots in error messages. Every input is checked (ConfigError / MapError naming what is wrong).

    The observation is :func:`areasearch.envs.observation.build_observation`'s, as the simulator's, except
    for what a map alone cannot tell: every reachable candidate is allowed (no memory of failed
    goals), and the historical-positions channel holds the robots' current cells and the past
    positions given (there is no trajectory); ``history_robots`` / ``history_goals`` hold -1 where
    a robot has fewer past points than the deepest list given.
    """
    cfg = (config or SearchConfig()).validate()
    radius = cfg.world.robot.radius_m
    poses = _checked_poses(poses)
    if not (is_real(progress) and 0.0 <= progress <= 1.0):
        raise ConfigError(f"progress must be a number in [0, 1], got {short(progress)}")
    n = len(poses)
    targets_xy = finite_rows("targets", [] if targets is None else targets, 2, "x, y in metres")
    for t in np.flatnonzero(~grid.contains(targets_xy)):
        x, y = targets_xy[t]
        raise ConfigError(f"target {t} at ({x:g}, {y:g}) lies outside the map ({grid.bounds_text()})")
    target_cells = grid.world_to_cell(targets_xy)
    cells = _robot_cells(grid, poses, radius, robot_names)
    free = _footprints_free(grid, cells, radius)
    start, found = _planning_cells(free, grid.occupied, cells, grid.cell_m, radius)
    if not found.all():
        _check_room(grid, free, radius)
    plan_grid = OccupancyMap(free, grid.occupied, grid.cell_m, grid.origin_xy, grid.source)
    keep = cfg.decisions.history
    history_robots = _history(grid, "past_positions", past_positions, n, keep, allow_none=False)
    history_goals = _history(grid, "past_goals", past_goals, n, keep, allow_none=True)
    cand = _candidates(plan_grid, grid.occupied, start, target_cells, cfg)
    targets_grid = np.zeros(grid.shape, dtype=bool)
    targets_grid[target_cells[:, 0], target_cells[:, 1]] = True
    obs = build_observation(
        cand,
        start,
        poses[:, 2],
        plan_grid.explored,
        grid.occupied,
        targets_grid,
        history_robots,
        history_goals,
        cell_m=grid.cell_m,
        progress=progress,
        config=cfg,
    )
    return Decision(obs=obs, candidates=cand, grid=plan_grid, robot_cells=start)


def _checked_poses(poses: Any) -> np.ndarray:
    """``poses`` as an (R, 3) float64 array, yaw normalised: ConfigError for no robot, more than
    :data:`~areasearch.config.MAX_ROBOTS`, or an entry that is not a finite number."""
    poses = finite_rows("poses", poses, 3, "x, y, yaw (metres, radians)")
    if len(poses) == 0:
        raise ConfigError("poses: give at least one robot")
    if len(poses) > MAX_ROBOTS:
        raise ConfigError(f"poses: {len(poses)} robots; the planners plan for at most {MAX_ROBOTS}")
    poses[:, 2] = normalise_yaw(poses[:, 2])
    return poses


def _candidates(
    plan_grid: OccupancyMap, occupied: np.ndarray, start: np.ndarray, target_cells: np.ndarray, cfg: SearchConfig
) -> Candidates:
    """The candidate goals of the robots at ``start`` (with their distance fields), as many as the
    settings keep."""
    return extract_candidates(
        plan_grid.explored,
        occupied,
        start,
        target_cells,
        np.arange(len(target_cells)),
        search_candidate_params(cfg, plan_grid.cell_m, unknown_margin_m=cfg.paths.unknown_margin_m),
    ).limit(cfg.candidates.max_candidates)
