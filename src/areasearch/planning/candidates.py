"""Pipeline stage "candidates": the candidate goals of the topological planner, with their distances.

DA-HGNN ("Topological Planner") assigns each robot a long-term goal among candidate nodes of two
types: *frontier nodes* (for exploration) and *interesting nodes* (for coverage: the discovered,
not yet covered targets); the robot-candidate edges carry the Fast Marching distance, and the
action planner ("Action Planner and Execution") drives there on the occupancy map with unknown
space traversable. This module turns the merged map M_t into those nodes:

* **frontier cells** (:func:`frontier_mask`): known-free cells with an unknown 4-neighbour;
* **frontier nodes**: 8-connected components of frontier cells, a long component cut into pieces
  of at most about ``cluster_m`` (bands of hop distance along the frontier from one of its ends);
  components with fewer than ``min_frontier_cells`` cells are dropped — unless no other reachable
  frontier node would remain while a tiny one is reachable (then the tiny reachable ones are kept:
  a map with reachable unknown space left always has a frontier node). Unreachable nodes are
  dropped. Node cell: the passable cell of the piece nearest its centroid, else the passable cell
  nearest the centroid within ``snap_m``, else the piece has no node;
* **target nodes**: one per discovered, uncovered target, at the passable cell nearest the target
  within ``snap_m`` (the target's own cell, unreachable, when there is none);
* **information gain** of a frontier node: unknown cells within ``sensor_range_m`` of its cell;
* **distances**: geodesic (FMM, :mod:`areasearch.planning.geodesic`) from every robot cell to every node.

The planning grid is the one of :func:`areasearch.planning.geodesic.planning_grid`: known obstacles inflated
by the robot footprint, unknown cells passable within ``unknown_margin_m`` of a frontier cell
(paths through unexplored space deeper than that are not considered; neither is the unknown band
behind a wall seen from one side). Everything is computed on the bounding box of the explored
region, the robots and the targets, grown by that margin: no passable cell lies outside it, so the
result equals the whole-map result (tested) at a fraction of the cost. About 6 ms per decision
for 4 robots on a medium map (``benchmarks/bench_candidates.py``), two thirds of it the FMM.

:meth:`Candidates.limit` caps the node count for fixed-size observations, the two kinds taking turns.

Units: cells are (iy, ix) int64 map indices (y northwards), distances metres, gain in cells.
Ordering is deterministic: frontier nodes by flat cell index (iy * W + ix), then targets by id.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import TYPE_CHECKING, Any, NamedTuple

import numba
import numpy as np

from .geodesic import (
    DEFAULT_METHOD,
    Box,
    Method,
    check_cells,
    disc_offsets,
    distances_to,
    fields_to,
    region_box,
    window_grid,
)

if TYPE_CHECKING:
    from ..sim.world import World


class CandidateKind(IntEnum):
    """Type of a candidate node (the paper's frontier and interesting nodes)."""

    FRONTIER = 0
    TARGET = 1


class Routes(NamedTuple):
    """Distance fields from the robots over the planning window of one decision: a path from a
    robot to any candidate is the steepest descent on that robot's field from the candidate."""

    box: Box
    """The window of the map the fields cover."""
    passable: np.ndarray
    """(h, w) bool passable cells of the window."""
    fields: np.ndarray
    """(R, h, w) float32 metres from each robot; exact up to the farthest candidate, +inf beyond."""


@dataclass(frozen=True, eq=False)
class Candidates:
    """The candidate goals of one decision (C nodes, R robots)."""

    cells: np.ndarray
    """(C, 2) int64 (iy, ix): the goal cell of each node, a passable cell (a target with no passable
    cell within ``snap_m`` keeps its own cell and is unreachable)."""
    kind: np.ndarray
    """(C,) int8 :class:`CandidateKind`."""
    size: np.ndarray
    """(C,) int64: frontier cells of the node's piece (1 for targets)."""
    gain: np.ndarray
    """(C,) float32: unknown cells within sensor range of the node's cell (0 for targets)."""
    target_id: np.ndarray
    """(C,) int64: index of the target in the world's target list, -1 for frontiers."""
    distance_m: np.ndarray
    """(R, C) float32 geodesic distance from each robot cell to each node cell, metres; +inf if unreachable."""
    offset_m: np.ndarray
    """(C,) float32: distance from the node's cell to what it stands for — the piece's centroid
    (frontiers) or the target's cell (targets), metres. A target is covered from its node when this
    is within the cover radius."""
    routes: Routes | None = None
    """The robots' distance fields the distances were read from, to plan paths with (optional)."""

    @property
    def reachable(self) -> np.ndarray:
        """(C,) bool: some robot has a finite distance to the node."""
        return np.isfinite(self.distance_m).any(axis=0)

    @property
    def is_frontier(self) -> np.ndarray:
        """(C,) bool: frontier nodes."""
        return self.kind == CandidateKind.FRONTIER

    def __len__(self) -> int:
        return int(self.cells.shape[0])

    def select(self, index: np.ndarray) -> Candidates:
        """The candidates at ``index`` (indices or a (C,) bool mask), in that order."""
        return Candidates(
            cells=self.cells[index],
            kind=self.kind[index],
            size=self.size[index],
            gain=self.gain[index],
            target_id=self.target_id[index],
            distance_m=self.distance_m[:, index],
            offset_m=self.offset_m[index],
            routes=self.routes,
        )

    def limit(self, n: int) -> Candidates:
        """At most ``n`` candidates, in their order: the two kinds take turns, each nearest first.

        Ranks each node within its kind by its distance to the nearest robot (unreachable last,
        ties by order), then keeps the ``n`` of lowest rank, the nearer on equal rank: so neither
        frontiers nor targets are crowded out while the other kind has nodes left.
        """
        if len(self) <= n:
            return self
        if self.distance_m.shape[0]:
            nearest = self.distance_m.min(axis=0)
        else:
            nearest = np.full(len(self), np.inf, dtype=np.float32)
        rank = np.empty(len(self), dtype=np.int64)
        for kind in CandidateKind:
            members = np.flatnonzero(self.kind == kind)
            rank[members[np.argsort(nearest[members], kind="stable")]] = np.arange(len(members))
        order = np.lexsort((np.arange(len(self)), nearest, rank))
        return self.select(np.sort(order[: max(n, 0)]))


def frontier_mask(explored: np.ndarray, occupied: np.ndarray) -> np.ndarray:
    """(H, W) bool: explored free cells (``explored & ~occupied``) with at least one unknown
    (``~explored``) 4-neighbour. Cells beyond the grid's edge are not unknown."""
    explored = np.asarray(explored, dtype=bool)
    unknown = np.pad(~explored, 1)  # (H+2, W+2), the border is not unknown
    near_unknown = unknown[:-2, 1:-1] | unknown[2:, 1:-1] | unknown[1:-1, :-2] | unknown[1:-1, 2:]
    return explored & ~np.asarray(occupied, dtype=bool) & near_unknown


# ---------------------------------------------------------------------------------- kernels


@numba.njit(cache=True, nogil=True)
def _frontier_nodes_kernel(
    frontier: np.ndarray, passable: np.ndarray, cell_m: float, cluster_m: float, offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cut the 8-connected components of ``frontier`` into pieces and give each its node cell, at
    the cost of one scan of the window plus work in proportion to the frontier cells. Returns per
    piece: size (P,), centroid (P, 2) float, node cell (P, 2) (-1 when none), size of its component (P,).

    Components are found in raster order; a component is cut into k = ceil(L / cluster_m) bands of
    hop distance from one end (the cell found last by a breadth-first search from its first cell),
    L = (longest hop distance + 1) cells. The node cell is the passable cell of the piece nearest
    its centroid (first in raster order on a tie), else the first passable cell of ``offsets``
    (nearest first) around the centroid's cell.
    """
    h, w = frontier.shape
    n = 0
    for y in range(h):
        for x in range(w):
            n += frontier[y, x]
    index = np.full((h, w), -1, dtype=np.int32)  # frontier cell -> its place in raster order
    ys = np.empty(n, dtype=np.int64)
    xs = np.empty(n, dtype=np.int64)
    k = 0
    for y in range(h):
        for x in range(w):
            if frontier[y, x]:
                index[y, x] = k
                ys[k] = y
                xs[k] = x
                k += 1
    hop = np.full(n, -1, dtype=np.int64)
    seen = np.zeros(n, dtype=np.bool_)
    queue = np.empty(n, dtype=np.int64)
    piece = np.empty(n, dtype=np.int64)
    comp_size = np.empty(n, dtype=np.int64)
    n_pieces = 0
    for first in range(n):
        if seen[first]:
            continue
        # 1) the component, breadth first from its first cell
        queue[0] = first
        seen[first] = True
        tail = 1
        head = 0
        while head < tail:
            c = queue[head]
            head += 1
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    ny = ys[c] + dy
                    nx = xs[c] + dx
                    if 0 <= ny < h and 0 <= nx < w:
                        j = index[ny, nx]
                        if j >= 0 and not seen[j]:
                            seen[j] = True
                            queue[tail] = j
                            tail += 1
        size = tail
        # 2) hop distances from its far end (the last cell found)
        end = queue[size - 1]
        hop[end] = 0
        queue[0] = end
        tail = 1
        head = 0
        longest = 0
        while head < tail:
            c = queue[head]
            head += 1
            d = hop[c]
            longest = max(longest, d)
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    ny = ys[c] + dy
                    nx = xs[c] + dx
                    if 0 <= ny < h and 0 <= nx < w:
                        j = index[ny, nx]
                        if j >= 0 and hop[j] < 0:
                            hop[j] = d + 1
                            queue[tail] = j
                            tail += 1
        span = longest + 1
        bands = max(1, min(span, int(math.ceil(span * cell_m / cluster_m - 1e-9))))
        for q in range(size):
            c = queue[q]
            piece[c] = n_pieces + hop[c] * bands // span
        for b in range(bands):
            comp_size[n_pieces + b] = size
        n_pieces += bands
    sizes = np.zeros(n_pieces, dtype=np.int64)
    centroid = np.zeros((n_pieces, 2))
    for c in range(n):
        p = piece[c]
        sizes[p] += 1
        centroid[p, 0] += ys[c]
        centroid[p, 1] += xs[c]
    for p in range(n_pieces):
        centroid[p, 0] /= sizes[p]
        centroid[p, 1] /= sizes[p]
    node = np.full((n_pieces, 2), -1, dtype=np.int64)
    best = np.full(n_pieces, np.inf)
    for c in range(n):  # raster order: the first cell wins a tie
        p = piece[c]
        if passable[ys[c], xs[c]]:
            d2 = (ys[c] - centroid[p, 0]) ** 2 + (xs[c] - centroid[p, 1]) ** 2
            if d2 < best[p]:
                best[p] = d2
                node[p, 0] = ys[c]
                node[p, 1] = xs[c]
    for p in range(n_pieces):
        if node[p, 0] < 0:
            cy = int(round(centroid[p, 0]))
            cx = int(round(centroid[p, 1]))
            for k in range(offsets.shape[0]):
                y = cy + offsets[k, 0]
                x = cx + offsets[k, 1]
                if 0 <= y < h and 0 <= x < w and passable[y, x]:
                    node[p, 0] = y
                    node[p, 1] = x
                    break
    return sizes, centroid, node, comp_size[:n_pieces].copy()


@numba.njit(cache=True, nogil=True)
def _snap_kernel(passable: np.ndarray, cells: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(N, 2) the first passable cell of ``offsets`` (nearest first) around each cell; -1 if none."""
    h, w = passable.shape
    out = np.full((cells.shape[0], 2), -1, dtype=np.int64)
    for i in range(cells.shape[0]):
        for k in range(offsets.shape[0]):
            y = cells[i, 0] + offsets[k, 0]
            x = cells[i, 1] + offsets[k, 1]
            if 0 <= y < h and 0 <= x < w and passable[y, x]:
                out[i, 0] = y
                out[i, 1] = x
                break
    return out


@numba.njit(cache=True, nogil=True)
def _gain_kernel(explored: np.ndarray, cells: np.ndarray, radius_cells: float) -> np.ndarray:
    """(N,) number of unknown (not ``explored``) cells whose centres lie within ``radius_cells`` of
    each cell's centre: per-row running counts of the rows the discs cover, then two lookups per
    disc row."""
    gh, gw = explored.shape
    r = int(math.floor(radius_cells))
    y0, y1 = gh, 0
    x0, x1 = gw, 0
    for i in range(cells.shape[0]):
        y0, y1 = min(y0, cells[i, 0] - r), max(y1, cells[i, 0] + r + 1)
        x0, x1 = min(x0, cells[i, 1] - r), max(x1, cells[i, 1] + r + 1)
    y0, y1, x0, x1 = max(y0, 0), min(y1, gh), max(x0, 0), min(x1, gw)
    row_prefix = np.zeros((y1 - y0, x1 - x0 + 1), dtype=np.int32)  # unknown cells before x, per row
    for y in range(y0, y1):
        count = 0
        for x in range(x0, x1):
            count += not explored[y, x]
            row_prefix[y - y0, x - x0 + 1] = count
    out = np.zeros(cells.shape[0], dtype=np.int64)
    for i in range(cells.shape[0]):
        cy = cells[i, 0]
        cx = cells[i, 1]
        total = 0
        for dy in range(-r, r + 1):
            y = cy + dy
            if y < y0 or y >= y1:
                continue
            half = int(math.floor(math.sqrt(radius_cells * radius_cells - dy * dy)))
            lo = max(cx - half, x0)
            hi = min(cx + half + 1, x1)
            if hi > lo:
                total += row_prefix[y - y0, hi - x0] - row_prefix[y - y0, lo - x0]
        out[i] = total
    return out


def information_gain(explored: np.ndarray, cells: np.ndarray, radius_m: float, cell_m: float) -> np.ndarray:
    """(N,) float32: unknown cells (``~explored``) whose centres lie within ``radius_m`` of each cell."""
    explored = np.asarray(explored, dtype=bool)
    cells = check_cells(cells, explored.shape, "cells")
    if len(cells) == 0:
        return np.zeros(0, dtype=np.float32)
    return _gain_kernel(explored, cells, radius_m / cell_m).astype(np.float32)


@numba.njit(cache=True, nogil=True)
def _open_frontier_kernel(
    frontier: np.ndarray, explored: np.ndarray, passable: np.ndarray, robots: np.ndarray, offsets: np.ndarray
) -> np.ndarray:
    """(h, w) bool: the frontier cells with an unknown 4-neighbour that a robot's footprint can
    reach, i.e. some passable cell joined to a robot cell (4-connected, as the FMM spreads) lies
    within ``offsets`` (the footprint radius plus half a cell's diagonal) of it. A frontier cell in a
    gap of a wall narrower than the footprint (a rasterised wall's missing pixel) has its unknown
    side beyond the wall: no robot can go and look there, so it is not open."""
    h, w = passable.shape
    reach = np.zeros((h, w), dtype=np.bool_)
    queue = np.empty(h * w, dtype=np.int64)
    tail = 0
    for i in range(robots.shape[0]):
        y, x = robots[i, 0], robots[i, 1]
        if 0 <= y < h and 0 <= x < w and passable[y, x] and not reach[y, x]:
            reach[y, x] = True
            queue[tail] = y * w + x
            tail += 1
    head = 0
    while head < tail:
        c = queue[head]
        head += 1
        y, x = c // w, c % w
        for k in range(4):
            ny = y + (k == 0) - (k == 1)
            nx = x + (k == 2) - (k == 3)
            if 0 <= ny < h and 0 <= nx < w and passable[ny, nx] and not reach[ny, nx]:
                reach[ny, nx] = True
                queue[tail] = ny * w + nx
                tail += 1
    out = np.zeros((h, w), dtype=np.bool_)
    for y in range(h):
        for x in range(w):
            if not frontier[y, x]:
                continue
            for k in range(4):
                uy = y + (k == 0) - (k == 1)
                ux = x + (k == 2) - (k == 3)
                if not (0 <= uy < h and 0 <= ux < w) or explored[uy, ux]:
                    continue
                for j in range(offsets.shape[0]):
                    ry = uy + offsets[j, 0]
                    rx = ux + offsets[j, 1]
                    if 0 <= ry < h and 0 <= rx < w and reach[ry, rx]:
                        out[y, x] = True
                        break
                if out[y, x]:
                    break
    return out


# ---------------------------------------------------------------------------------- extraction


def planning_window(
    explored: np.ndarray,
    occupied: np.ndarray,
    robot_cells: np.ndarray,
    extra_cells: np.ndarray,
    *,
    cell_m: float,
    radius_m: float,
    unknown_margin_m: float = 0.5,
    crop: bool = True,
    box: Box | None = None,
    impassable: np.ndarray | None = None,
    inflated: np.ndarray | None = None,
) -> tuple[Box, np.ndarray, np.ndarray]:
    """The grid that candidates and paths are planned on, cropped to where it can be passable.

    Returns the window ``box`` and, inside it, the passable cells (:func:`.geodesic.planning_grid`: known
    obstacles inflated, unknown cells passable within ``unknown_margin_m`` of a frontier cell, the
    robots' cells forced passable; ``impassable`` (H, W) cells, e.g. the action planner's collision
    map, blocked except the robots' cells) and the frontier cells. Every passable cell is an
    explored cell, a robot cell, or within the unknown margin of a frontier (hence explored) cell;
    the box holds them all and ``extra_cells`` (targets, goals), so cropping changes no distance. A
    given ``box`` is used as it is (a smaller window, e.g. around one robot and its goal).
    ``inflated``: the known obstacles already inflated for this cell size and radius
    (:class:`~areasearch.planning.geodesic.InflatedObstacles`), which saves that step.
    """
    shape = explored.shape
    if box is None:
        margin = int(math.floor(unknown_margin_m / cell_m + 1e-9)) + 1
        box = (
            region_box(explored, margin, np.concatenate([robot_cells, extra_cells]))
            if crop
            else Box(0, shape[0], 0, shape[1])
        )
    if impassable is not None and np.shape(impassable) != shape:
        raise ValueError(f"impassable {np.shape(impassable)} must have the map's shape {shape}")
    passable, frontier = window_grid(
        explored,
        occupied,
        box,
        cell_m,
        radius_m,
        unknown_margin_m=unknown_margin_m,
        keep_free=robot_cells,
        impassable=None if impassable is None else np.asarray(impassable, dtype=bool),
        inflated=inflated,
    )
    return box, passable, frontier


def extract_candidates(
    explored: np.ndarray,
    occupied: np.ndarray,
    robot_cells: np.ndarray,
    target_cells: np.ndarray,
    target_ids: np.ndarray,
    *,
    cell_m: float,
    radius_m: float,
    sensor_range_m: float = 3.2,
    min_frontier_cells: int = 3,
    cluster_m: float = 1.0,
    snap_m: float = 0.5,
    unknown_margin_m: float = 0.5,
    method: Method = DEFAULT_METHOD,
    crop: bool = True,
    keep_routes: bool = False,
    impassable: np.ndarray | None = None,
    inflated: np.ndarray | None = None,
) -> Candidates:
    """Candidate goals of the merged map, with robot-candidate geodesic distances.

    Args:
        explored, occupied: (H, W) bool map channels (``Mapper.explored``, ``Mapper.occupied``).
        robot_cells: (R, 2) cells of the robots (the FMM sources; forced passable).
        target_cells: (T, 2) cells of the discovered, uncovered targets; ``target_ids`` (T,) their
            indices in the world's target list.
        cell_m: cell size; radius_m: robot footprint radius (obstacle inflation), metres.
        sensor_range_m: radius of the information-gain disc, metres (the camera range).
        min_frontier_cells: smaller frontier components are dropped (unless nothing else is left).
        cluster_m: longest frontier piece, metres (pieces are cut along hop distance, so a
            diagonal piece may reach ``sqrt(2) * cluster_m``).
        snap_m: how far from a piece's centroid or a target a goal cell may be sought, metres.
        unknown_margin_m: unknown cells farther than this from a frontier cell are impassable.
        method: distance method of :mod:`areasearch.planning.geodesic`.
        crop: work on the bounding box of the region that can be passable (the default) or on the
            whole grid; the results are equal, the box is faster.
        keep_routes: also return the robots' distance fields (:class:`Routes`, ``"fmm"`` only), so
            the action planner can read each robot's first path off them instead of re-planning.
        impassable: (H, W) bool cells to treat as obstacles besides the inflated known ones (the
            action planner's collision map), so that distances and routes avoid what the robots
            will avoid; the robots' own cells stay passable.
        inflated: (H, W) bool, the known obstacles already inflated by the footprint
            (:class:`~areasearch.planning.geodesic.InflatedObstacles` kept up to date by the caller), which
            saves recomputing them; it must match ``occupied``, ``cell_m`` and ``radius_m``.

    Raises ValueError for robot or target cells outside the grid.
    """
    explored = np.asarray(explored, dtype=bool)
    occupied = np.asarray(occupied, dtype=bool)
    if explored.shape != occupied.shape or explored.ndim != 2:
        raise ValueError(f"explored {explored.shape} and occupied {occupied.shape} must be 2-D grids of one shape")
    shape = explored.shape
    robots = check_cells(robot_cells, shape, "robot_cells")
    targets = check_cells(target_cells, shape, "target_cells")
    ids = np.asarray(target_ids, dtype=np.int64).reshape(-1)
    if len(ids) != len(targets):
        raise ValueError(f"target_ids has {len(ids)} entries for {len(targets)} target cells")
    order = np.argsort(ids, kind="stable")
    targets, ids = targets[order], ids[order]

    box, passable, frontier = planning_window(
        explored,
        occupied,
        robots,
        targets,
        cell_m=cell_m,
        radius_m=radius_m,
        unknown_margin_m=unknown_margin_m,
        crop=crop,
        impassable=impassable,
        inflated=inflated,
    )
    origin = box.origin
    box_robots = robots - origin
    snap = disc_offsets(snap_m / cell_m)
    # frontier cells whose unknown side no robot can reach (gaps in walls) are not frontiers
    reach = disc_offsets(radius_m / cell_m + math.sqrt(0.5))
    frontier = _open_frontier_kernel(frontier, explored[box.slices], passable, box_robots, reach)

    # frontier pieces and their node cells
    size, centroid, node, comp_size = _frontier_nodes_kernel(frontier, passable, cell_m, cluster_m, snap)
    has_node = node[:, 0] >= 0
    node, size, centroid, comp_size = node[has_node], size[has_node], centroid[has_node], comp_size[has_node]
    # pieces sharing a node cell (rare: snapped to one cell) become one node of their summed size
    flat = (node[:, 0] + origin[0]) * shape[1] + node[:, 1] + origin[1]
    _, f_first, f_inverse = np.unique(flat, return_index=True, return_inverse=True)
    f_size = np.bincount(f_inverse, weights=size).astype(np.int64)
    f_big = np.bincount(f_inverse, weights=comp_size >= min_frontier_cells) > 0
    f_node = node[f_first]
    f_offset = np.hypot(*(f_node - centroid[f_first]).T) * cell_m

    # target node cells
    t_node = _snap_kernel(passable, targets - origin, snap)
    t_missing = t_node[:, 0] < 0
    t_node[t_missing] = (targets - origin)[t_missing]
    t_offset = np.hypot(*(t_node - (targets - origin)).T) * cell_m

    goals = np.concatenate([f_node, t_node])
    routes = None
    if keep_routes and method == "fmm":
        fields, dist = fields_to(passable, box_robots, goals, cell_m)  # (R, h, w), (R, F + T)
        routes = Routes(box, passable, fields)
    else:
        dist = distances_to(passable, box_robots, goals, cell_m, method=method)  # (R, F + T)
    dist[:, len(f_node) :][:, t_missing] = np.inf  # a target's own cell is a goal only if passable

    f_reach = np.isfinite(dist[:, : len(f_node)]).any(axis=0)
    keep = f_reach & f_big
    if not keep.any():
        keep = f_reach  # never drop the last reachable frontier: unknown space remains behind it
    f_keep = np.flatnonzero(keep)
    n_t = len(t_node)
    pick = np.concatenate([f_keep, len(f_node) + np.arange(n_t)])
    cells = goals[pick] + origin
    kind = np.concatenate([np.full(len(f_keep), CandidateKind.FRONTIER), np.full(n_t, CandidateKind.TARGET)])
    gain = np.zeros(len(pick), dtype=np.float32)
    gain[: len(f_keep)] = information_gain(explored, cells[: len(f_keep)], sensor_range_m, cell_m)
    return Candidates(
        cells=cells.astype(np.int64),
        kind=kind.astype(np.int8),
        size=np.concatenate([f_size[f_keep], np.ones(n_t, dtype=np.int64)]),
        gain=gain,
        target_id=np.concatenate([np.full(len(f_keep), -1, dtype=np.int64), ids]),
        distance_m=np.ascontiguousarray(dist[:, pick], dtype=np.float32),
        offset_m=np.concatenate([f_offset[f_keep], t_offset]).astype(np.float32),
        routes=routes,
    )


def extract_from_world(world: World, **kwargs: Any) -> Candidates:
    """:func:`extract_candidates` on a :class:`~areasearch.sim.world.World`'s merged map, robots and
    discovered-uncovered targets, with the cell size, footprint radius and camera range of its
    scene and config (``kwargs`` override the other settings, e.g. ``cluster_m``)."""
    if world.scene is None or world.mapper is None:
        raise RuntimeError("extract_from_world called before World.reset")
    scene, config = world.scene, world.config
    open_targets = np.flatnonzero(world.discovered & ~world.covered)
    return extract_candidates(
        world.mapper.explored,
        world.mapper.occupied,
        scene.world_to_cell(world.poses[:, :2]),
        world.target_cells[open_targets],
        open_targets,
        cell_m=scene.cell_m,
        radius_m=config.robot.radius_m,
        sensor_range_m=config.camera.max_range_m,
        **kwargs,
    )
