"""Communication between the robots: who is linked to whom in a step (:func:`links`), the groups the links
split the team into (:func:`groups`), and what each robot last heard of its team-mates (:class:`CommState`).

The models are those of :class:`~areasearch.config.comm.CommConfig` (``full``, ``disc``, ``signal``); the
world evaluates them on the true map and the true positions, since the radio goes by where the robots are,
not where they believe they are. For ``signal``, the straight segment between two robots is walked cell by
cell over the true occupancy grid with the project's ray walk (:mod:`areasearch.sim.raycast`), summing the
exact length that lies in obstacle cells and in free cells (cells off the grid count as obstacle, as the
scenes treat the outside); :func:`segment_lengths_reference` measures the same from first principles (the
sorted grid-line crossings, each piece classified by its midpoint) for the tests.

Groups are the connected components of the links: messages hop, so a chain of links connects its ends.
Within a group every member knows where every other member is now; of a robot outside its group, it knows
the freshest position any member of its group has heard (IR2 merges its robots' beliefs the same way,
``env.py``), which the planners show where it was last heard of.

Units: metres, map frame; grid cells ``(iy, ix)`` of ``cell_m`` metres whose corner ``(0, 0)`` is at
``origin_xy``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from ..config.comm import CommConfig
from .raycast import ray_in_grid, ray_next, ray_start

_SLIVER_M = 1e-9
"""Obstacle lengths below this (metres) are rounding, not a stretch of the segment: a walk through a grid
corner visits a cell for a length of 0 up to rounding."""


class Shadowing(NamedTuple):
    """The shadowing of a ``signal`` episode, dB, shared by every pair of robots."""

    free_db: float
    """Added to the free-space term (IR2's ``X_g``)."""
    obstacle_db: float
    """Added to the obstacle term (IR2's ``K``)."""


NO_SHADOWING = Shadowing(0.0, 0.0)


def draw_shadowing(config: CommConfig, rng: np.random.Generator) -> Shadowing:
    """An episode's shadowing: two independent uniform draws from the configured range (IR2 draws once
    per environment; a world draws once per episode from its seeded generator)."""
    low, high = float(config.shadowing_min_db), float(config.shadowing_max_db)
    if high <= low:
        return Shadowing(low, low)
    free_db, obstacle_db = rng.uniform(low, high, size=2)
    return Shadowing(float(free_db), float(obstacle_db))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def segment_lengths(occupied: np.ndarray, ax: float, ay: float, bx: float, by: float) -> tuple[float, float]:
    """``(obstacle, free)``: the lengths of the segment from ``(ax, ay)`` to ``(bx, by)`` (grid cells as
    units, coordinates in cells) that lie in occupied cells (or off the grid) and in free cells."""
    gh, gw = occupied.shape
    length = math.hypot(bx - ax, by - ay)
    if length == 0.0:
        return 0.0, 0.0
    ray = ray_start(ax, ay, (bx - ax) / length, (by - ay) / length)
    obstacle = 0.0
    free = 0.0
    while True:
        t_exit = min(ray.t_x, ray.t_y, length)
        piece = t_exit - ray.t_enter
        if ray_in_grid(ray, gh, gw) and not occupied[ray.iy, ray.ix]:
            free += piece
        else:
            obstacle += piece
        if t_exit >= length:
            return obstacle, free
        ray = ray_next(ray)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def pair_lengths(occupied: np.ndarray, cells_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(obstacle, free)``, (R, R) each, symmetric, zero diagonal: :func:`segment_lengths` between every
    pair of the (R, 2) points ``cells_xy`` (x, y in cells), walked once per pair from the lower index."""
    n = cells_xy.shape[0]
    obstacle = np.zeros((n, n))
    free = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            o, f = segment_lengths(occupied, cells_xy[i, 0], cells_xy[i, 1], cells_xy[j, 0], cells_xy[j, 1])
            obstacle[i, j] = obstacle[j, i] = o
            free[i, j] = free[j, i] = f
    return obstacle, free


def segment_lengths_reference(occupied: np.ndarray, ax: float, ay: float, bx: float, by: float) -> tuple[float, float]:
    """:func:`segment_lengths` in plain Python from first principles: every crossing of a grid line
    between the ends, sorted; each piece between two crossings lies in the cell holding its midpoint."""
    gh, gw = occupied.shape
    length = math.hypot(bx - ax, by - ay)
    if length == 0.0:
        return 0.0, 0.0
    ts = [0.0, 1.0]
    for a, b in ((ax, bx), (ay, by)):
        lo, hi = min(a, b), max(a, b)
        ts += [(k - a) / (b - a) for k in range(math.floor(lo) + 1, math.ceil(hi)) if lo < k < hi]
    ts.sort()
    obstacle = free = 0.0
    for t0, t1 in itertools.pairwise(ts):
        tm = (t0 + t1) / 2
        ix, iy = math.floor(ax + tm * (bx - ax)), math.floor(ay + tm * (by - ay))
        piece = (t1 - t0) * length
        if 0 <= ix < gw and 0 <= iy < gh and not occupied[iy, ix]:
            free += piece
        else:
            obstacle += piece
    return obstacle, free


def received_power_dbm(
    config: CommConfig, obstacle_m: np.ndarray, free_m: np.ndarray, shadowing: Shadowing = NO_SHADOWING
) -> np.ndarray:
    """The ``signal`` model's received power, dBm, over segments of ``obstacle_m`` and ``free_m`` metres
    (arrays of one shape): the formula of :mod:`areasearch.config.comm`."""
    obstacle_m = np.asarray(obstacle_m, dtype=np.float64)
    free_m = np.asarray(free_m, dtype=np.float64)
    crossed = obstacle_m > _SLIVER_M
    ratio = np.maximum(obstacle_m, config.obstacle_ref_m) / config.obstacle_ref_m
    loss = np.where(crossed, 10.0 * config.exponent_obstacle * np.log10(ratio) + shadowing.obstacle_db, 0.0)
    far = free_m >= config.ref_distance_m
    ratio = np.maximum(free_m, config.ref_distance_m) / config.ref_distance_m
    loss = loss + np.where(far, 10.0 * config.exponent_free * np.log10(ratio) + shadowing.free_db, 0.0)
    return config.tx_power_dbm - config.ref_loss_db - loss


def links(
    config: CommConfig,
    positions_xy: np.ndarray,
    occupied: np.ndarray,
    cell_m: float,
    origin_xy: tuple[float, float] | np.ndarray = (0.0, 0.0),
    *,
    shadowing: Shadowing = NO_SHADOWING,
) -> np.ndarray:
    """(R, R) bool, symmetric, diagonal True: which robots at ``positions_xy`` ((R, 2) metres, map frame)
    can talk to which under ``config``, over the true map ``occupied`` ((H, W) bool, True = obstacle) of
    ``cell_m`` metres per cell with cell ``(0, 0)``'s corner at ``origin_xy``. ``shadowing`` is the
    episode's (:func:`draw_shadowing`; ``signal`` only)."""
    xy = np.asarray(positions_xy, dtype=np.float64).reshape(-1, 2)
    n = xy.shape[0]
    if config.model == "full":
        return np.ones((n, n), dtype=bool)
    if config.model == "disc":
        gap = xy[:, None, :] - xy[None, :, :]
        linked = np.hypot(gap[..., 0], gap[..., 1]) <= config.range_m
    else:
        cells = (xy - np.asarray(origin_xy, dtype=np.float64)) / cell_m
        grid = np.ascontiguousarray(occupied, dtype=np.bool_)
        obstacle, free = pair_lengths(grid, cells)
        linked = received_power_dbm(config, obstacle * cell_m, free * cell_m, shadowing) > config.threshold_dbm
    linked = linked & linked.T
    np.fill_diagonal(linked, True)
    return linked


def groups(adjacency: np.ndarray) -> list[np.ndarray]:
    """The connected components of the (R, R) bool ``adjacency`` (links hop: a chain connects its ends),
    each a sorted int64 array of robot indices, ordered by their first member."""
    adjacency = np.asarray(adjacency, dtype=bool)
    n = adjacency.shape[0]
    label = np.full(n, -1, dtype=np.int64)
    found: list[np.ndarray] = []
    for start in range(n):
        if label[start] >= 0:
            continue
        label[start] = len(found)
        frontier = [start]
        while frontier:
            i = frontier.pop()
            for j in np.flatnonzero((adjacency[i] | adjacency[:, i]) & (label < 0)):
                label[j] = len(found)
                frontier.append(int(j))
        found.append(np.flatnonzero(label == len(found)).astype(np.int64))
    return found


@dataclass
class CommState:
    """What each robot last heard of its team-mates: ``positions[i, j]`` is where robot ``i`` last heard
    robot ``j`` was (metres; NaN if never) and ``steps[i, j]`` the step it was there (-1 if never).
    ``positions[i, i]`` is robot ``i``'s own position at the last update."""

    positions: np.ndarray
    """(R, R, 2) float64, metres."""
    steps: np.ndarray
    """(R, R) int64."""

    @classmethod
    def new(cls, num_robots: int) -> CommState:
        """Nobody has heard of anybody yet."""
        return cls(np.full((num_robots, num_robots, 2), np.nan), np.full((num_robots, num_robots), -1, np.int64))

    def update(self, step: int, positions_xy: np.ndarray, adjacency: np.ndarray) -> list[np.ndarray]:
        """Share news at ``step``, the robots standing at ``positions_xy`` ((R, 2) metres) and linked by
        ``adjacency``: each member of a group learns where every member is now, and of every robot
        outside the group, the freshest position any member has (ties go to the lowest member's). Returns
        the groups (:func:`groups`)."""
        xy = np.asarray(positions_xy, dtype=np.float64).reshape(-1, 2)
        found = groups(adjacency)
        for group in found:
            rows = np.ix_(group, group)
            freshest = group[np.argmax(self.steps[group], axis=0)]  # per robot j, the member that heard last
            columns = np.arange(self.steps.shape[1])
            best_steps = self.steps[freshest, columns]
            best_positions = self.positions[freshest, columns]
            self.steps[group] = best_steps
            self.positions[group] = best_positions
            self.steps[rows] = step
            self.positions[group[:, None], group[None, :]] = xy[group][None, :, :]
        return found

    def heard(self, robot: int) -> np.ndarray:
        """(R,) bool: the team-mates ``robot`` has heard of at some step (itself included once updated)."""
        return self.steps[robot] >= 0

    def age(self, robot: int, step: int) -> np.ndarray:
        """(R,) int64: steps since ``robot`` last heard of each team-mate at ``step`` (-1 if never)."""
        steps = self.steps[robot]
        return np.where(steps >= 0, step - steps, -1)
