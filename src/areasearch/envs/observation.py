"""The goal planners' observation of one decision: one builder for the simulator and for real maps.

:class:`areasearch.envs.goal.AreaSearchEnv` (the simulator's decisions) and
:func:`areasearch.service.assign.build_decision` (a decision on a user's own partial map) both build their
observation with :func:`build_observation`, so a planner sees the same thing, with the same keys,
shapes, units and pooling, in both.

Spec (R robots, C = ``candidates.max_candidates``, H = ``decisions.history``, S = ``decisions.map_cells``),
a ``dict`` of:

- ``map`` (7, S, S) float32 in [0, 1], the paper's map channels (:data:`MAP_CHANNELS`): robots,
  historical positions of all robots, frontiers, targets (discovered, uncovered), obstacles,
  explored, historical goals; downsampled by ``map_scale`` (max-pooling; the explored channel is
  averaged) and zero-padded (:func:`pool_map_channels`).
- ``map_scale`` (1,) float32: cells of the full map per observation cell (>= ``map_downsample``;
  :func:`map_scale`).
- ``cell_m`` (1,) float32: the map's cell size in metres (cell indices below times this are metres).
- ``robots`` (R, 3) float32: cell row, cell column, yaw (rad) of each robot.
- ``candidates`` (C, 5) float32: cell row, cell column, kind (0 frontier, 1 target), frontier size
  (cells), information gain (unknown cells within sensor range); zero rows past the end.
- ``candidate_mask`` (C,) int8: 1 for real candidates.
- ``distances`` (R, C) float32: geodesic (FMM) distance in metres from each robot, +inf where
  unreachable or padded.
- ``action_mask`` (R, C) int8: 1 where robot r may choose candidate i (real and reachable).
- ``history_robots``, ``history_goals`` (H, R, 2) float32 cells of the last H decisions (newest
  first; -1 where a robot has no point, e.g. no goal), with ``history_mask`` (H,) int8; rows past
  the decisions held are zero.
- ``progress`` (1,) float32: share of the mission time spent (steps taken / ``max_steps``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba
import numpy as np

from ..config import DecisionConfig, SearchConfig
from ..planning.candidates import Candidates

MAP_CHANNELS = ("robots", "history_positions", "frontiers", "targets", "obstacles", "explored", "history_goals")
"""Channel order of the observation map (the paper's 7-channel map)."""


def map_scale(shape: Sequence[int], decisions: DecisionConfig) -> int:
    """Full-map cells per observation-map cell for a map of ``shape`` (H, W): the smallest factor,
    at least ``decisions.map_downsample``, that fits the map's longer side in ``decisions.map_cells``."""
    return max(decisions.map_downsample, math.ceil(max(shape) / decisions.map_cells))


@numba.njit(cache=True, nogil=True)
def pool_kernel(
    explored: np.ndarray,
    occupied: np.ndarray,
    targets: np.ndarray,
    visited: np.ndarray,
    y0: int,
    y1: int,
    x0: int,
    x1: int,
    f: int,
    out: np.ndarray,
) -> None:
    """Pool the map channels of cells [y0, y1) x [x0, x1) into ``out`` (7, S, S) float32 blocks of f x f.

    ``explored``, ``occupied``, ``targets``, ``visited``: (H, W) bool grids of the same shape; the
    cell range must lie inside them and ``[y0, y1) // f``, ``[x0, x1) // f`` inside ``out``. Sets
    (never clears) channel 1 (historical positions: ``visited``), 2 (frontiers: explored, not
    occupied cells with an unexplored 4-neighbour inside the grid), 3 (``targets``) and 4
    (``occupied``) to 1 in every block holding such a cell, and adds 1 / f² to channel 5 (explored)
    per explored cell, so a block of ``out`` zeroed beforehand holds its explored share. Channels 0
    and 6 are not touched."""
    h, w = explored.shape
    share = 1.0 / (f * f)
    for iy in range(y0, y1):
        by = iy // f
        for ix in range(x0, x1):
            bx = ix // f
            if visited[iy, ix]:
                out[1, by, bx] = 1.0
            if targets[iy, ix]:
                out[3, by, bx] = 1.0
            if occupied[iy, ix]:
                out[4, by, bx] = 1.0
            if explored[iy, ix]:
                out[5, by, bx] += share
                if not occupied[iy, ix] and (
                    (iy > 0 and not explored[iy - 1, ix])
                    or (iy < h - 1 and not explored[iy + 1, ix])
                    or (ix > 0 and not explored[iy, ix - 1])
                    or (ix < w - 1 and not explored[iy, ix + 1])
                ):
                    out[2, by, bx] = 1.0


def pool_map_channels(
    explored: np.ndarray,
    occupied: np.ndarray,
    targets: np.ndarray,
    visited: np.ndarray,
    robot_cells: np.ndarray,
    goal_cells: np.ndarray,
    scale: int,
    size: int,
) -> np.ndarray:
    """The (7, size, size) float32 observation map (:data:`MAP_CHANNELS`) of a map, pooled by ``scale``.

    ``explored``, ``occupied``, ``targets`` (uncovered known targets) and ``visited`` (cells the
    robots stood on) are (H, W) bool grids; ``robot_cells`` (R, 2) and ``goal_cells`` (N, 2) are
    integer cells (iy, ix) drawn in channels 0 (robots) and 6 (historical goals), rows with a
    negative entry skipped. Each observation cell is the max over its ``scale`` x ``scale`` block
    (the explored channel: the explored share of the block); the map sits at the canvas' [0, 0]
    corner, the rest is zero, and whatever falls beyond the canvas is cut off. Only the bounding
    box of the explored cells is read: channels 1-5 are zero outside it.
    """
    out = np.zeros((len(MAP_CHANNELS), size, size), dtype=np.float32)
    rows = np.flatnonzero(explored.any(axis=1))
    if len(rows):
        cols = np.flatnonzero(explored.any(axis=0))
        y1, x1 = min(rows[-1] + 1, size * scale), min(cols[-1] + 1, size * scale)
        pool_kernel(explored, occupied, targets, visited, rows[0], y1, cols[0], x1, scale, out)
    for channel, cells in ((0, robot_cells), (6, goal_cells)):
        cells = np.asarray(cells).reshape(-1, 2).astype(np.int64)
        cells = cells[(cells >= 0).all(axis=1)] // scale
        cells = cells[(cells < size).all(axis=1)]
        out[channel, cells[:, 0], cells[:, 1]] = 1.0
    return out


def build_observation(
    candidates: Candidates,
    robot_cells: np.ndarray,
    yaw: np.ndarray,
    explored: np.ndarray,
    occupied: np.ndarray,
    targets: np.ndarray,
    history_robots: np.ndarray,
    history_goals: np.ndarray,
    *,
    cell_m: float,
    progress: float,
    config: SearchConfig,
    allowed: np.ndarray | None = None,
    visited: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """The observation of one decision (the module docstring's spec).

    Args:
        candidates: the decision's candidate goals (at most ``candidates.max_candidates``), in
            observation order; their ``distance_m`` (R, K) fills ``distances``.
        robot_cells: (R, 2) integer cells of the robots (the ``robots`` rows and map channel 0).
        yaw: (R,) robot headings, radians.
        explored, occupied, targets: (H, W) bool grids of the map: known cells, obstacles, cells of
            uncovered known targets.
        history_robots, history_goals: (D_r, R, 2) and (D_g, R, 2) cells of the robots' positions
            and goals at their past decisions, newest first, -1 where a robot has none; both at most
            ``decisions.history`` deep. The decisions held are D = max(D_r, D_g) (``history_mask[:D]``
            is 1); the shallower array is padded with -1 rows to D, rows past D are zero. Map
            channel 6 marks every goal cell of ``history_goals``.
        cell_m: the map's cell size, metres.
        progress: share of the mission time spent, in [0, 1].
        config: the settings (``candidates.max_candidates`` and ``decisions``).
        allowed: (R, K) bool, the candidates each robot may choose (``action_mask``); None: the
            reachable ones (finite distance).
        visited: (H, W) bool, the cells of map channel 1 (historical positions); None: the robots'
            current cells and the cells of ``history_robots``.

    How the two callers differ: the simulator passes its failed-goal memory as ``allowed`` and the
    whole trajectory of the robots (every cell they stood on) as ``visited``, and its history
    arrays are equally deep; a real map has no trajectory nor goal memory, so
    :func:`areasearch.service.assign.build_decision` passes neither (channel 1 is then the robots' current
    and past decision cells) and gives the past positions and goals the user has, which may differ
    in depth.
    """
    n = len(robot_cells)
    c_max, h = config.candidates.max_candidates, config.decisions.history
    k = len(candidates)
    if k > c_max:
        raise ValueError(f"{k} candidates, more than candidates.max_candidates ({c_max})")
    depth = max(len(history_robots), len(history_goals))
    if depth > h:
        raise ValueError(f"{depth} past decisions, more than decisions.history ({h})")
    obs_candidates, candidate_mask, distances, action_mask = _candidate_arrays(candidates, n, c_max, allowed)
    hist_r, hist_g, hist_mask = _history_arrays(history_robots, history_goals, n, h, depth)
    robots = np.zeros((n, 3), dtype=np.float32)
    robots[:, :2] = robot_cells
    robots[:, 2] = yaw
    if visited is None:
        visited = _visited_cells(explored.shape, robot_cells, hist_r[:depth])
    scale = map_scale(explored.shape, config.decisions)
    return {
        "map": pool_map_channels(
            explored, occupied, targets, visited, robot_cells, hist_g[:depth], scale, config.decisions.map_cells
        ),
        "map_scale": np.array([scale], dtype=np.float32),
        "cell_m": np.array([cell_m], dtype=np.float32),
        "robots": robots,
        "candidates": obs_candidates,
        "candidate_mask": candidate_mask,
        "distances": distances,
        "action_mask": action_mask,
        "history_robots": hist_r,
        "history_goals": hist_g,
        "history_mask": hist_mask,
        "progress": np.array([progress], dtype=np.float32),
    }


def _candidate_arrays(
    cand: Candidates, n: int, c_max: int, allowed: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The ``candidates``, ``candidate_mask``, ``distances`` and ``action_mask`` entries, padded to ``c_max``."""
    k = len(cand)
    obs_candidates = np.zeros((c_max, 5), dtype=np.float32)
    obs_candidates[:k, 0:2] = cand.cells
    obs_candidates[:k, 2] = cand.kind
    obs_candidates[:k, 3] = cand.size
    obs_candidates[:k, 4] = cand.gain
    candidate_mask = np.zeros(c_max, dtype=np.int8)
    candidate_mask[:k] = 1
    distances = np.full((n, c_max), np.inf, dtype=np.float32)
    distances[:, :k] = cand.distance_m
    action_mask = np.zeros((n, c_max), dtype=np.int8)
    action_mask[:, :k] = np.isfinite(cand.distance_m) if allowed is None else allowed
    return obs_candidates, candidate_mask, distances, action_mask


def _history_arrays(
    history_robots: np.ndarray, history_goals: np.ndarray, n: int, h: int, depth: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``history_robots``, ``history_goals`` and ``history_mask`` entries: ``depth`` decisions
    held (-1 where an array is shallower), zero rows past them."""
    hist_r = np.zeros((h, n, 2), dtype=np.float32)
    hist_g = np.zeros((h, n, 2), dtype=np.float32)
    hist_mask = np.zeros(h, dtype=np.int8)
    hist_r[:depth] = -1.0
    hist_g[:depth] = -1.0
    hist_r[: len(history_robots)] = history_robots
    hist_g[: len(history_goals)] = history_goals
    hist_mask[:depth] = 1
    return hist_r, hist_g, hist_mask


def _visited_cells(shape: tuple[int, ...], robot_cells: np.ndarray, history_robots: np.ndarray) -> np.ndarray:
    """(H, W) bool: the robots' current cells and their cells at the past decisions (rows with a
    negative entry skipped)."""
    visited = np.zeros(shape, dtype=bool)
    for cells in (np.asarray(robot_cells), history_robots.reshape(-1, 2).astype(np.int64)):
        cells = cells[(cells >= 0).all(axis=1)]
        visited[cells[:, 0], cells[:, 1]] = True
    return visited
