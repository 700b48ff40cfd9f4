"""Pipeline stage "candidates": the candidate goals of the topological planner, with their distances.

DA-HGNN ("Topological Planner") assigns each robot a long-term goal among candidate nodes of two
types: *frontier nodes* (for exploration) and *interesting nodes* (for coverage: the discovered,
not yet covered targets); the robot-candidate edges carry the Fast Marching distance, and the
action planner ("Action Planner and Execution") drives there on the occupancy map with unknown
space traversable. This module turns the merged map M_t into those nodes:

* **frontier cells** (:func:`~areasearch.planning.frontiers.frontier_mask`): known-free cells with an
  unknown 4-neighbour;
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

The planning grid is the one of :func:`areasearch.planning.grid.planning_grid`: known obstacles inflated
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

import numpy as np

from .frontiers import frontier_nodes_kernel, information_gain, open_frontier_kernel, snap_kernel
from .geodesic import DEFAULT_METHOD, Method, block_grid, distances_to, fields_to
from .grid import Box, check_cells, disc_offsets, region_box
from .window import window_grid

if TYPE_CHECKING:
    from ..config import SearchConfig
    from ..sim.world import World


class CandidateKind(IntEnum):
    """Type of a candidate node (the paper's frontier and interesting nodes)."""

    FRONTIER = 0
    TARGET = 1


class Routes(NamedTuple):
    """Distance fields from the robots over the planning window of one decision, to read a robot's
    path to any candidate off (:func:`areasearch.planning.paths.route_path`): the steepest descent on
    that robot's field from the candidate, refined on the window's own cells when the fields were
    marched on blocks of cells."""

    box: Box
    """The window of the map the fields cover."""
    passable: np.ndarray
    """(h, w) bool passable cells of the window."""
    fields: np.ndarray
    """(R, ceil(h / block), ceil(w / block)) float32 metres from each robot's block; exact up to the
    farthest candidate, +inf beyond."""
    robots: np.ndarray
    """(R, 2) int64 the robots' cells in the window."""
    block: int = 1
    """Cells per side of a field's cell (:attr:`CandidateParams.distance_block`)."""


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

    Returns the window ``box`` and, inside it, the passable cells (:func:`.grid.planning_grid`: known
    obstacles inflated, unknown cells passable within ``unknown_margin_m`` of a frontier cell, the
    robots' cells forced passable; ``impassable`` (H, W) cells, e.g. the action planner's collision
    map, blocked except the robots' cells) and the frontier cells. Every passable cell is an
    explored cell, a robot cell, or within the unknown margin of a frontier (hence explored) cell;
    the box holds them all and ``extra_cells`` (targets, goals), so cropping changes no distance. A
    given ``box`` is used as it is (a smaller window, e.g. around one robot and its goal).
    ``inflated``: the known obstacles already inflated for this cell size and radius
    (:class:`~areasearch.planning.grid.InflatedObstacles`), which saves that step.
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


@dataclass(frozen=True)
class CandidateParams:
    """The settings of one candidate extraction (:func:`extract_candidates`)."""

    cell_m: float
    """Cell size, metres."""
    radius_m: float
    """Robot footprint radius (obstacle inflation), metres."""
    sensor_range_m: float = 3.2
    """Radius of the information-gain disc, metres (the camera range)."""
    min_frontier_cells: int = 3
    """Smaller frontier components are dropped (unless nothing else is left)."""
    cluster_m: float = 1.0
    """Longest frontier piece, metres (pieces are cut along hop distance, so a diagonal piece may
    reach ``sqrt(2) * cluster_m``)."""
    snap_m: float = 0.5
    """How far from a piece's centroid or a target a goal cell may be sought, metres."""
    unknown_margin_m: float = 0.5
    """Unknown cells farther than this from a frontier cell are impassable, metres."""
    method: Method = DEFAULT_METHOD
    """Distance method of :mod:`areasearch.planning.geodesic`."""
    crop: bool = True
    """Work on the bounding box of the region that can be passable (the default) or on the whole
    grid; the results are equal, the box is faster."""
    keep_routes: bool = False
    """Also return the robots' distance fields (:class:`Routes`, ``"fmm"`` only), so the action
    planner can read each robot's first path off them instead of re-planning."""
    distance_block: int = 1
    """The distances are marched on blocks of this many by this many cells of the window
    (:func:`~areasearch.planning.geodesic.block_grid`: a block is passable where any of its cells is;
    a cell's distance is its block's), 1: on the cells themselves. Two on a map of 5 cm cells marches
    NCM's 10 cm cells, in about a quarter of the time, the distances off by the blocks' size."""


def search_candidate_params(cfg: SearchConfig, cell_m: float, **overrides: Any) -> CandidateParams:
    """The :class:`CandidateParams` a search with settings ``cfg`` on a grid of ``cell_m`` metres
    extracts with (distance fields kept for the action planner); ``overrides`` set further fields."""
    return CandidateParams(
        cell_m=cell_m,
        radius_m=cfg.world.robot.radius_m,
        sensor_range_m=cfg.world.camera.max_range_m,
        min_frontier_cells=cfg.candidates.min_frontier_cells,
        cluster_m=cfg.candidates.cluster_m,
        keep_routes=True,
        distance_block=distance_block(cfg.candidates.distance_cell_m, cell_m),
        **overrides,
    )


def extract_candidates(
    explored: np.ndarray,
    occupied: np.ndarray,
    robot_cells: np.ndarray,
    target_cells: np.ndarray,
    target_ids: np.ndarray,
    params: CandidateParams,
    *,
    impassable: np.ndarray | None = None,
    inflated: np.ndarray | None = None,
) -> Candidates:
    """Candidate goals of the merged map, with robot-candidate geodesic distances.

    Args:
        explored, occupied: (H, W) bool map channels (``Mapper.explored``, ``Mapper.occupied``).
        robot_cells: (R, 2) cells of the robots (the FMM sources; forced passable).
        target_cells: (T, 2) cells of the discovered, uncovered targets; ``target_ids`` (T,) their
            indices in the world's target list.
        params: cell size, footprint radius and the extraction's settings (:class:`CandidateParams`).
        impassable: (H, W) bool cells to treat as obstacles besides the inflated known ones (the
            action planner's collision map), so that distances and routes avoid what the robots
            will avoid; the robots' own cells stay passable.
        inflated: (H, W) bool, the known obstacles already inflated by the footprint
            (:class:`~areasearch.planning.grid.InflatedObstacles` kept up to date by the caller), which
            saves recomputing them; it must match ``occupied``, ``params.cell_m`` and ``params.radius_m``.

    Raises ValueError for robot or target cells outside the grid.
    """
    explored, occupied, robots, targets, ids = _checked_inputs(
        explored, occupied, robot_cells, target_cells, target_ids
    )
    p = params
    box, passable, frontier = planning_window(
        explored,
        occupied,
        robots,
        targets,
        cell_m=p.cell_m,
        radius_m=p.radius_m,
        unknown_margin_m=p.unknown_margin_m,
        crop=p.crop,
        impassable=impassable,
        inflated=inflated,
    )
    origin = box.origin
    box_robots = robots - origin
    snap = disc_offsets(p.snap_m / p.cell_m)
    f_node, f_size, f_big, f_offset = _frontier_nodes(
        explored, box, passable, frontier, box_robots, snap, p, explored.shape[1]
    )
    t_node, t_missing, t_offset = _target_nodes(passable, targets - origin, snap, p.cell_m)

    goals = np.concatenate([f_node, t_node])
    dist, routes = _distances(box, passable, box_robots, goals, p)  # (R, F + T)
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
    gain[: len(f_keep)] = information_gain(explored, cells[: len(f_keep)], p.sensor_range_m, p.cell_m)
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


def _checked_inputs(
    explored: np.ndarray,
    occupied: np.ndarray,
    robot_cells: np.ndarray,
    target_cells: np.ndarray,
    target_ids: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(explored, occupied, robots, targets, ids) as bool grids and int64 cells, the targets in
    the order of their ids; ValueError for grids of two shapes, cells outside or a count mismatch."""
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
    return explored, occupied, robots, targets[order], ids[order]


def _frontier_nodes(
    explored: np.ndarray,
    box: Box,
    passable: np.ndarray,
    frontier: np.ndarray,
    box_robots: np.ndarray,
    snap: np.ndarray,
    p: CandidateParams,
    map_width: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The frontier nodes of the window: (node cells (F, 2) in window cells, sizes (F,) int64,
    whether some piece of the node has a component of ``min_frontier_cells`` or more (F,) bool,
    the distance from the node cell to the piece's centroid (F,) metres)."""
    origin = box.origin
    # frontier cells whose unknown side no robot can reach (gaps in walls) are not frontiers
    reach = disc_offsets(p.radius_m / p.cell_m + math.sqrt(0.5))
    frontier = open_frontier_kernel(frontier, explored[box.slices], passable, box_robots, reach)
    # frontier pieces and their node cells
    size, centroid, node, comp_size = frontier_nodes_kernel(frontier, passable, p.cell_m, p.cluster_m, snap)
    has_node = node[:, 0] >= 0
    node, size, centroid, comp_size = node[has_node], size[has_node], centroid[has_node], comp_size[has_node]
    # pieces sharing a node cell (rare: snapped to one cell) become one node of their summed size
    flat = (node[:, 0] + origin[0]) * map_width + node[:, 1] + origin[1]
    _, f_first, f_inverse = np.unique(flat, return_index=True, return_inverse=True)
    f_size = np.bincount(f_inverse, weights=size).astype(np.int64)
    f_big = np.bincount(f_inverse, weights=comp_size >= p.min_frontier_cells) > 0
    f_node = node[f_first]
    f_offset = np.hypot(*(f_node - centroid[f_first]).T) * p.cell_m
    return f_node, f_size, f_big, f_offset


def _target_nodes(
    passable: np.ndarray, box_targets: np.ndarray, snap: np.ndarray, cell_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The target nodes: (node cells (T, 2) in window cells, the target's own cell where no
    passable cell is within ``snap``; which have none (T,) bool; node-to-target distance (T,) metres)."""
    t_node = snap_kernel(passable, box_targets, snap)
    t_missing = t_node[:, 0] < 0
    t_node[t_missing] = box_targets[t_missing]
    t_offset = np.hypot(*(t_node - box_targets).T) * cell_m
    return t_node, t_missing, t_offset


def _distances(
    box: Box, passable: np.ndarray, box_robots: np.ndarray, goals: np.ndarray, p: CandidateParams
) -> tuple[np.ndarray, Routes | None]:
    """(R, G) metres from each robot to each goal over the window (on blocks of
    ``distance_block`` cells), and with ``keep_routes`` (``"fmm"`` only) the robots' distance fields."""
    k = p.distance_block
    grid, robots, stops = passable, box_robots, goals
    if k > 1:
        grid, robots, stops = block_grid(passable, k), box_robots // k, goals // k
    if p.keep_routes and p.method == "fmm":
        fields, dist = fields_to(grid, robots, stops, p.cell_m * k)  # (R, h / k, w / k), (R, G)
        return dist, Routes(box, passable, fields, box_robots, k)
    return distances_to(grid, robots, stops, p.cell_m * k, method=p.method), None


def distance_block(distance_cell_m: float, cell_m: float) -> int:
    """Cells per side of the blocks the distances are marched on: the whole number of ``cell_m``
    cells nearest ``distance_cell_m`` metres, at least one (``distance_cell_m`` 0: one)."""
    return max(1, round(distance_cell_m / cell_m + 1e-9))


def extract_from_world(world: World, **kwargs: Any) -> Candidates:
    """:func:`extract_candidates` on a :class:`~areasearch.sim.world.World`'s merged map, robots and
    discovered-uncovered targets, with the cell size, footprint radius and camera range of its
    scene and config (``kwargs`` override the other fields of :class:`CandidateParams`, e.g.
    ``cluster_m``)."""
    if world.scene is None or world.mapper is None:
        raise RuntimeError("extract_from_world called before World.reset")
    scene, config = world.scene, world.config
    open_targets = np.flatnonzero(world.discovered & ~world.covered)
    params = CandidateParams(
        cell_m=scene.cell_m, radius_m=config.robot.radius_m, sensor_range_m=config.camera.max_range_m, **kwargs
    )
    return extract_candidates(
        world.mapper.explored,
        world.mapper.occupied,
        scene.world_to_cell(world.believed_poses[:, :2]),
        world.target_map_cells[open_targets],
        open_targets,
        params,
    )
