"""Pipeline stage "candidates" (its metric): geodesic distances on the planning grid by the Fast Marching Method.

DA-HGNN ("Topological Planner", cross-graph edges) measures robot-to-candidate distances with the
Fast Marching Method (FMM); its action planner ("Action Planner and Execution", after NCM, Ye et
al. 2022) plans with FMM on the global occupancy map, unknown space traversable.

* :func:`distance_fields` — (N, H, W) distance from each source cell over passable cells;
  +inf where impassable or unreachable.
* :func:`distance_field` — one source; optionally the march stops once given cells (a path
  planner's start) are settled.
* :func:`distances_to` — (N, G) distances from sources to goal cells; the march stops once every
  goal is settled.
* :func:`fields_to` — the fields and the goals' distances of one march that stops at the goals.
* :func:`block_grid` — a coarser grid to march on: blocks of k × k cells, passable where any of
  their cells is.

The grid they run on: :mod:`areasearch.planning.grid` (:func:`~areasearch.planning.grid.planning_grid`
— where a robot centre may be: known obstacles inflated by the footprint, unknown cells passable,
optionally only near explored cells; :func:`~areasearch.planning.grid.region_box` — the bounding
box of a region plus a margin, to crop the grid; :class:`~areasearch.planning.grid.InflatedObstacles`
— the inflated obstacles of a growing map, updated at the cost of the cells that changed) and
:mod:`areasearch.planning.window` (:func:`~areasearch.planning.window.window_grid` — the planning
grid of a window of the map at a cost in proportion to the window: rows packed 64 cells to a machine
word). The march itself: :mod:`areasearch.planning.fmm`.

Units: cells are (iy, ix) integer indices (y northwards); distances are metres between cell centres
(the source cell is 0, its 4-neighbours ``cell_m``, its diagonal neighbours ``sqrt(2) cell_m``).
A source on an impassable cell is made passable for its own march.

Methods (``method=``):

``"skfmm"`` — the reference
    scikit-fmm (``skfmm.distance``, second order) on a masked array, impassable cells masked:
    phi = -1 on the source cell, +1 elsewhere. The zero contour then lies half a cell from the
    source centre, so half a cell is added to every distance (the source itself is 0). Cells
    skfmm leaves masked (not reached) are +inf.
``"fmm"`` — the default, our numba kernel
    The same second-order upwind scheme (4-neighbour stencil; per axis the smaller settled
    neighbour, by the one-sided second-order difference where the cell beyond it is settled and
    not larger, else first order), with exact Euclidean values on the 8 cells around the source,
    an untidy bucket queue (O(1) push and pop) instead of a heap, and early termination once the
    goals are settled. On the bundled maps (``scene.free`` passable, random free sources, cells
    farther than 1 m from the source) it reaches the same cells as ``"skfmm"``, differs from it by
    0.2-0.4 % on average and at most 2.6 % (the largest differences at the 1 m cut, where skfmm's
    half-cell source contour still shows), is within about 0.5 % mean / 1.3 % max of the Euclidean
    distance in an empty room, and is about 4x faster; hence the default.
    ``tests/planning/test_geodesic.py`` bounds the difference to skfmm (mean 1 %, max 5 %) and to Euclid
    (mean 1 %, max 2 %). Per-map figures and timings: see docs/performance.md.

Cropping: distances to candidates, which all lie in or next to the explored region, do not depend
on unknown space far from it, so :mod:`areasearch.planning.candidates` makes unknown cells passable only
within a margin of a frontier cell (:func:`~areasearch.planning.grid.planning_grid`
``(..., unknown_margin_m=, margin_from=)``: the unknown space just beyond the frontiers and small
unseen holes in explored rooms, not the unknown band behind every wall seen from one side) and runs
on the bounding box of the explored region grown by that margin
(:func:`~areasearch.planning.grid.region_box`). No passable cell lies outside the box, so the
result equals the whole-grid result for that planning grid; what the margin gives up is shortcuts
through unexplored space deeper than the margin (a path is then longer, or rarely unreachable).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from .fmm import run_fmm, skfmm_fields
from .grid import check_cells

Method = Literal["fmm", "skfmm"]
METHODS: tuple[Method, ...] = ("fmm", "skfmm")
DEFAULT_METHOD: Method = "fmm"


def _prepare(passable: np.ndarray, sources: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    passable = np.asarray(passable, dtype=bool)
    if passable.ndim != 2:
        raise ValueError(f"passable must be a 2-D grid, got shape {passable.shape}")
    return passable, check_cells(sources, passable.shape, "sources")


def distance_fields(
    passable: np.ndarray, sources: np.ndarray, cell_m: float, *, method: Method = DEFAULT_METHOD
) -> np.ndarray:
    """(N, H, W) float32 geodesic distance in metres from each of ``sources`` (N, 2) cells.

    Over ``passable`` cells only (4-neighbour FMM stencil); +inf on impassable and unreachable
    cells. A source on an impassable cell is treated as passable for its own field. Raises
    ValueError when a source lies outside the grid.
    """
    passable, sources = _prepare(passable, sources)
    if method == "skfmm":
        cells = skfmm_fields(passable, sources)
    elif method == "fmm":
        fields, _ = run_fmm(
            passable, sources, np.zeros((0, 2), dtype=np.int64), stop=False, want_fields=True, scale=cell_m
        )
        return fields
    else:
        raise ValueError(f"unknown method {method!r}; use one of {', '.join(METHODS)}")
    return (cells * cell_m).astype(np.float32)


def distance_field(
    passable: np.ndarray,
    source: np.ndarray,
    cell_m: float,
    *,
    stop_at: np.ndarray | None = None,
    method: Method = DEFAULT_METHOD,
) -> np.ndarray:
    """(H, W) float32 geodesic distance in metres from one ``source`` cell (iy, ix).

    As :func:`distance_fields` for a single source. With ``stop_at`` (K, 2) cells the ``"fmm"``
    march ends once all of them are settled (a path planner's start): every cell nearer than the
    farthest of them is exact, farther cells may read +inf.
    """
    passable, sources = _prepare(passable, np.asarray(source).reshape(1, 2))
    if method == "fmm" and stop_at is not None:
        stops = check_cells(stop_at, passable.shape, "stop_at")
        fields, _ = run_fmm(passable, sources, stops, stop=True, want_fields=True, scale=cell_m)
        return fields[0]
    return distance_fields(passable, sources, cell_m, method=method)[0]


def fields_to(
    passable: np.ndarray, sources: np.ndarray, goals: np.ndarray, cell_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Distance fields (N, H, W) and distances to the goals (N, G), float32 metres, by the ``"fmm"``
    method stopping once every goal is settled: the fields are exact wherever they are nearer than
    the farthest goal (so a path from any goal back to its source can be read off them)."""
    passable, sources = _prepare(passable, sources)
    goals = check_cells(goals, passable.shape, "goals")
    fields, cells = run_fmm(passable, sources, goals, stop=True, want_fields=True, scale=cell_m)
    return fields, (cells * cell_m).astype(np.float32)


def block_grid(passable: np.ndarray, k: int) -> np.ndarray:
    """(ceil(H / k), ceil(W / k)) bool: block (by, bx) of ``k`` × ``k`` cells (cells (k by .. k by +
    k - 1, k bx ..)) is passable where any of its cells is.

    Why any, not all: a doorway the robot barely passes is often a single cell wide on the map's
    grid, so blocks that needed all their cells passable would close it; with any, every passable
    cell lies in a passable block and no reachable goal is lost (a block may join cells that are not
    joined on the map: an obstacle thinner than two cells, which the footprint's inflation leaves
    only where the caller blocks single cells, e.g. bump marks). Cell (iy, ix) is in block
    (iy // k, ix // k)."""
    passable = np.asarray(passable, dtype=bool)
    if k < 1:
        raise ValueError(f"block size must be at least 1, got {k}")
    if k == 1:
        return passable.copy()
    h, w = passable.shape
    hb, wb = -(-h // k), -(-w // k)
    blocks = np.zeros((hb, wb), dtype=bool)
    for dy in range(k):  # k * k strided ORs: several times faster than a reduction over a reshape
        for dx in range(k):
            part = passable[dy::k, dx::k]
            blocks[: part.shape[0], : part.shape[1]] |= part
    return blocks


def distances_to(
    passable: np.ndarray,
    sources: np.ndarray,
    goals: np.ndarray,
    cell_m: float,
    *,
    method: Method = DEFAULT_METHOD,
) -> np.ndarray:
    """(N, G) float32 geodesic distance in metres from each source cell to each goal cell.

    Equals ``distance_fields(...)[:, goals[:, 0], goals[:, 1]]``; the ``"fmm"`` method stops each
    march as soon as every goal is settled. +inf for impassable or unreachable goals.
    """
    passable, sources = _prepare(passable, sources)
    goals = check_cells(goals, passable.shape, "goals")
    if method == "skfmm":
        cells = skfmm_fields(passable, sources)[:, goals[:, 0], goals[:, 1]]
    elif method == "fmm":
        _, cells = run_fmm(passable, sources, goals, stop=True, want_fields=False)
    else:
        raise ValueError(f"unknown method {method!r}; use one of {', '.join(METHODS)}")
    return (cells * cell_m).astype(np.float32)
