"""Goals for your own robots on your own map: the goal planners as one library call.

A robot team that already runs SLAM and localisation has an occupancy grid (a ROS ``map_server``
YAML, a PNG, or the ``nav_msgs/OccupancyGrid`` array) and the robots' poses in the map frame.
:func:`assign_goals` turns those into one long-term goal per robot, chosen by any registered goal
planner (classical or learned), with the planned path to it::

    from areasearch.service.assign import assign_goals

    for a in assign_goals("my_map.yaml", [(1.0, 2.0, 0.0), (1.5, 2.0, 3.14)], method="voronoi"):
        print(a.robot, a.kind, a.goal_xy, a.distance_m, len(a.path_xy))

The grid is a *partial* map, as a SLAM system produces it: known-free cells are explored, occupied
cells are obstacles, unknown cells are unexplored. Everything the planners see comes from that map,
never from a ground truth: the same pipeline stages as the simulator's decisions
(:func:`areasearch.planning.candidates.extract_candidates` for frontier and target nodes with FMM distances,
the observation of :class:`areasearch.envs.goal.AreaSearchEnv` (:func:`areasearch.envs.observation.build_observation`),
``planner.assign(obs)``, and the
path read off each robot's FMM distance field by steepest descent, as the action planner does).

Frames and units: poses are (x, y, yaw) in metres and radians in the map frame, whose ``origin``
(the map-frame position of the south-west corner of cell [0, 0]) is honoured; grids are indexed
``[iy, ix]`` with ``iy`` growing northwards (ROS: row 0 of ``OccupancyGrid.data`` is at the origin;
the image's bottom row). Goals and paths come back in the same frame, metres.

Rules for what a real map holds:

* a cell is free when its occupancy is below ``free_thresh``, occupied above ``occupied_thresh``,
  unknown otherwise (map_server's trinary reading; ``OccupancyGrid`` value -1 is unknown);
* unknown cells under a robot's footprint are free (the robot stands there; a fresh SLAM map often
  has not seen the floor under its own sensor), and so is an unknown pocket of at most 1 m² enclosed
  by known cells that a robot stands in (a sensor's blind spot around itself);
* a robot whose centre is nearer a wall than the planner's clearance (localisation noise, a tight
  spot) plans from the nearest free cell that has the clearance, if one lies within that clearance;
  its path starts at its own position;
* a robot centre on an occupied cell, outside the grid, non-finite, more than
  :data:`~areasearch.config.MAX_ROBOTS` robots, or two robots closer than the footprint's diameter
  (their footprints overlap), is an error (:class:`~areasearch.errors.ConfigError`), as is a map with no free
  cell or no free cell that can hold the footprint (:class:`~areasearch.errors.MapError`).

A robot gets ``kind == "none"`` (no goal, empty path) when no candidate is reachable for it: the
map is finished, or the robot is walled in. A yaw is any finite angle (normalised to [-pi, pi)). A
target that no robot can take as its goal (in a wall or in unknown space with no reachable cell
within the snap distance, unreachable, or over the candidate limit) is listed, with the reason, in
the returned list's ``dropped_targets`` (:class:`Assignments`).
"""

from __future__ import annotations

import functools
import io
import json
import math
import os
import re
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from PIL import Image
from scipy import ndimage

from ..config import MAX_ROBOTS, SearchConfig, override
from ..envs.observation import build_observation
from ..errors import ConfigError, MapError
from ..folderlock import write_atomic
from ..inputs import LIMIT_VARIABLES, clip, is_real, limits, parse_json, read_bytes, real_number, short
from ..planners import GoalPlanner, choose_planner
from ..planning.candidates import CandidateKind, Candidates, extract_candidates
from ..planning.geodesic import clearance_threshold_m, disc_offsets, planning_grid
from ..planning.paths import descend
from ..sim.scene import (
    MAP_IMAGE_MODES,
    check_origin,
    check_resolution,
    check_thresholds,
    open_image,
    read_map_image,
    read_ros_map,
    read_ros_yaml,
)

FREE_THRESH, OCCUPIED_THRESH = 0.196, 0.65
MAX_PATH_STEP_M = 100.0
"""Largest spacing of the points of a returned path, metres."""
"""map_server's default thresholds on the occupancy probability p (PNGs without a YAML, arrays)."""

KINDS = {int(CandidateKind.FRONTIER): "frontier", int(CandidateKind.TARGET): "target"}
"""Goal type names by :class:`~areasearch.planning.candidates.CandidateKind`; ``"none"``: no goal."""


# ---------------------------------------------------------------------------------- the map


@dataclass(frozen=True, eq=False)
class OccupancyMap:
    """A partial occupancy grid in the ROS map frame: known-free, occupied and (the rest) unknown cells."""

    free: np.ndarray
    """(H, W) bool: known free cells."""
    occupied: np.ndarray
    """(H, W) bool: occupied cells (never also free)."""
    cell_m: float
    """Cell size (``resolution``), metres."""
    origin_xy: tuple[float, float] = (0.0, 0.0)
    """Map-frame (x, y) of the south-west corner of cell [0, 0], metres (ROS ``origin``, yaw 0)."""
    source: str = "grid"
    """Where the map came from, for messages."""

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.free.shape[0]), int(self.free.shape[1]))

    @functools.cached_property
    def explored(self) -> np.ndarray:
        """(H, W) bool: known cells, free or occupied."""
        return self.free | self.occupied

    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) map-frame (x, y) metres -> (..., 2) cells (iy, ix); may lie outside the grid."""
        yx = np.asarray(xy, dtype=np.float64)[..., ::-1]
        return np.floor((yx - (self.origin_xy[1], self.origin_xy[0])) / self.cell_m).astype(np.int64)

    def cell_to_world(self, cells: np.ndarray) -> np.ndarray:
        """(..., 2) cells (iy, ix) -> (..., 2) map-frame (x, y) metres of the cell centres."""
        xy = np.asarray(cells, dtype=np.float64)[..., ::-1]
        return np.asarray(self.origin_xy) + (xy + 0.5) * self.cell_m

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """(N,) bool: the (N, 2) map-frame points (x, y), metres, lie on the grid; compared as floats,
        so any finite number can be asked about (:meth:`world_to_cell` only for points on the grid)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        x0, y0 = self.origin_xy
        h, w = self.shape
        with np.errstate(all="ignore"):
            return (
                (xy[:, 0] >= x0)
                & (xy[:, 0] < x0 + w * self.cell_m)
                & (xy[:, 1] >= y0)
                & (xy[:, 1] < y0 + h * self.cell_m)
            )

    def inside(self, cells: np.ndarray) -> np.ndarray:
        """(N,) bool: the (N, 2) cells lie in the grid."""
        cells = np.asarray(cells).reshape(-1, 2)
        h, w = self.shape
        return (cells[:, 0] >= 0) & (cells[:, 0] < h) & (cells[:, 1] >= 0) & (cells[:, 1] < w)

    def bounds_text(self) -> str:
        x0, y0 = self.origin_xy
        h, w = self.shape
        return f"x in [{x0:g}, {x0 + w * self.cell_m:g}), y in [{y0:g}, {y0 + h * self.cell_m:g})"


def _check_resolution(source: str, resolution: Any) -> float:
    return check_resolution(source, resolution)


def _check_origin(source: str, origin: Any) -> tuple[float, float]:
    return check_origin(source, origin)


def _make_map(
    source: str, free: np.ndarray, occupied: np.ndarray, cell_m: float, origin: tuple[float, float]
) -> OccupancyMap:
    if free.ndim != 2 or free.shape[0] < 3 or free.shape[1] < 3:
        raise MapError(f"{source}: a map must be a 2-D grid of at least 3x3 cells, got shape {free.shape}")
    bound = limits().max_map_cells
    if free.size > bound:
        raise MapError(
            f"{source}: {free.shape[1]} x {free.shape[0]} cells, more than the limit of {bound:,} "
            f"(environment variable {LIMIT_VARIABLES['max_map_cells']})"
        )
    if not free.any():
        raise MapError(f"{source}: the map has no free cell")
    return OccupancyMap(
        free=np.ascontiguousarray(free & ~occupied),
        occupied=np.ascontiguousarray(occupied),
        cell_m=cell_m,
        origin_xy=origin,
        source=source,
    )


def occupancy_from_array(
    data: Any,
    resolution: float,
    origin: Sequence[float] = (0.0, 0.0),
    *,
    free_thresh: float = FREE_THRESH,
    occupied_thresh: float = OCCUPIED_THRESH,
    source: str = "grid",
) -> OccupancyMap:
    """An :class:`OccupancyMap` from an ``nav_msgs/OccupancyGrid``-style array.

    ``data`` (H, W) integers: -1 unknown, 0-100 occupancy probability in percent; row 0 is the
    southern edge (``np.asarray(msg.data).reshape(msg.info.height, msg.info.width)``). A boolean
    array is read as free (True) / occupied (False), with nothing unknown. Cells below
    ``free_thresh`` * 100 are free, above ``occupied_thresh`` * 100 occupied, the rest unknown.
    """
    cell_m = _check_resolution(source, resolution)
    xy = _check_origin(source, origin)
    check_thresholds(source, free_thresh, occupied_thresh)
    arr = np.asarray(data)
    if arr.ndim != 2:
        raise MapError(f"{source}: the grid must be a 2-D array (H, W), got shape {arr.shape}")
    if arr.size > limits().max_map_cells:
        raise MapError(
            f"{source}: {arr.shape[1]} x {arr.shape[0]} cells, more than the limit of {limits().max_map_cells:,} "
            f"(environment variable {LIMIT_VARIABLES['max_map_cells']})"
        )
    if arr.dtype == bool:
        return _make_map(source, arr.copy(), ~arr, cell_m, xy)
    if arr.dtype.kind not in "iu":
        raise MapError(f"{source}: the grid must hold integers (-1 unknown, 0-100 occupancy), got dtype {arr.dtype}")
    values = arr.astype(np.int64)
    bad = (values < -1) | (values > 100)
    if bad.any():
        iy, ix = np.argwhere(bad)[0]
        raise MapError(f"{source}: cell (iy={iy}, ix={ix}) holds {values[iy, ix]}; values must be -1 or 0-100")
    known = values >= 0
    free = known & (values < free_thresh * 100.0)
    occupied = known & (values > occupied_thresh * 100.0)
    return _make_map(source, free, occupied, cell_m, xy)


def load_occupancy(
    path: str | Path, resolution: float | None = None, origin: Sequence[float] | None = None
) -> OccupancyMap:
    """Read an occupancy map file.

    * ``.yaml`` / ``.yml``: a ROS ``map_server`` map; resolution, origin, thresholds, ``negate`` and
      ``mode`` come from the file (checked as :func:`areasearch.sim.scene.load_ros_yaml` checks them).
    * ``.png`` / ``.pgm``: an 8- or 16-bit image (grey, or colour / palette read as grey; 16-bit grey by
      its full range, a PGM by its maxval) read with
      map_server's defaults (dark occupied, light free, mid grey unknown: the bundled maps' 0 / 255
      / 127 and map_saver's 0 / 254 / 205 both work); needs ``resolution``, ``origin`` defaults to
      (0, 0).
    """
    path = Path(path).expanduser()
    source = str(path)
    suffix = path.suffix.lower()
    if suffix in (".yaml", ".yml"):
        if resolution is not None or origin is not None:
            raise MapError(f"{source}: a ROS map YAML sets its own resolution and origin; do not give them")
        ros = read_ros_yaml(path)  # every check of the YAML, one clear message each
        free, occupied = read_ros_map(ros)
        return _make_map(source, free, occupied, ros.resolution, ros.origin_xy)
    if suffix in (".png", ".pgm"):
        if resolution is None:
            raise MapError(f"{source}: a map image needs its resolution (metres per cell); a .yaml map carries it")
        cell_m = _check_resolution(source, resolution)
        xy = _check_origin(source, (0.0, 0.0) if origin is None else origin)
        image = open_image(path)
        if image.mode not in MAP_IMAGE_MODES:
            raise MapError(f"{source}: expected an 8- or 16-bit grey, colour or palette image, got mode {image.mode!r}")
        free, occupied = read_map_image(image, "trinary", False, FREE_THRESH, OCCUPIED_THRESH, source)
        return _make_map(source, free, occupied, cell_m, xy)
    if not os.path.lexists(path):
        raise MapError(f"{source}: no such file")
    raise MapError(f"{source}: expected a ROS map .yaml, or a .png / .pgm image with a resolution")


def save_occupancy_yaml(grid: OccupancyMap, path: str | Path) -> Path:
    """Write ``grid`` as a ROS ``map_server`` map: ``<path>`` (YAML) and a PNG beside it with
    map_saver's values (254 free, 0 occupied, 205 unknown). Both are written atomically."""
    path = Path(path)
    image_path = path.with_suffix(".png")
    pixels = np.full(grid.shape, 205, dtype=np.uint8)
    pixels[grid.free] = 254
    pixels[grid.occupied] = 0
    buffer = io.BytesIO()
    Image.fromarray(np.flipud(pixels)).save(buffer, format="PNG")
    write_atomic(image_path, buffer.getvalue(), "map image")  # never over a device or a named pipe
    doc = {
        "image": image_path.name,
        "resolution": grid.cell_m,
        "origin": [grid.origin_xy[0], grid.origin_xy[1], 0.0],
        "negate": 0,
        "occupied_thresh": OCCUPIED_THRESH,
        "free_thresh": FREE_THRESH,
        "mode": "trinary",
    }
    return write_atomic(path, yaml.safe_dump(doc, sort_keys=False).encode("utf-8"), "map YAML")


def as_occupancy(
    grid: OccupancyMap | str | Path | np.ndarray, resolution: float | None = None, origin: Sequence[float] | None = None
) -> OccupancyMap:
    """Any accepted map form as an :class:`OccupancyMap` (see :func:`assign_goals`)."""
    if isinstance(grid, OccupancyMap):
        if resolution is not None or origin is not None:
            raise MapError(f"{grid.source}: an OccupancyMap carries its own resolution and origin")
        return grid
    if isinstance(grid, (str, Path)):
        return load_occupancy(grid, resolution, origin)
    if resolution is None:
        raise MapError("grid: an array map needs its resolution (metres per cell)")
    return occupancy_from_array(grid, resolution, (0.0, 0.0) if origin is None else origin)


# ---------------------------------------------------------------------------------- inputs


def _leaves(value: Any) -> list[Any]:
    """The items of nested lists and tuples (NumPy arrays are left whole: their dtype says what they hold)."""
    if not isinstance(value, (list, tuple)):
        return [value] if not isinstance(value, np.ndarray) else []
    return [leaf for item in value for leaf in _leaves(item)]


def _finite_rows(name: str, value: Any, width: int, what: str) -> np.ndarray:
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
            xy = _finite_rows(f"{name}[{r}][{k}]", point, 2, "x, y in metres")
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
    poses = _finite_rows("poses", poses, 3, "x, y, yaw (metres, radians)")
    if len(poses) == 0:
        raise ConfigError("poses: give at least one robot")
    if len(poses) > MAX_ROBOTS:
        raise ConfigError(f"poses: {len(poses)} robots; the planners plan for at most {MAX_ROBOTS}")
    poses[:, 2] = normalise_yaw(poses[:, 2])
    if not (is_real(progress) and 0.0 <= progress <= 1.0):
        raise ConfigError(f"progress must be a number in [0, 1], got {short(progress)}")
    n = len(poses)
    targets_xy = _finite_rows("targets", [] if targets is None else targets, 2, "x, y in metres")
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

    cand = extract_candidates(
        plan_grid.explored,
        grid.occupied,
        start,
        target_cells,
        np.arange(len(target_cells)),
        cell_m=grid.cell_m,
        radius_m=radius,
        sensor_range_m=cfg.world.camera.max_range_m,
        min_frontier_cells=cfg.candidates.min_frontier_cells,
        cluster_m=cfg.candidates.cluster_m,
        unknown_margin_m=cfg.paths.unknown_margin_m,
        keep_routes=True,
    ).limit(cfg.candidates.max_candidates)

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


# ---------------------------------------------------------------------------------- goals


@dataclass(frozen=True)
class Assignment:
    """One robot's goal, in the map frame."""

    robot: int
    """Index of the robot in the poses given."""
    kind: str
    """``"frontier"`` (explore there), ``"target"`` (cover that target) or ``"none"`` (no reachable goal)."""
    goal_xy: tuple[float, float] | None
    """Goal position (x, y), metres (the centre of the goal cell); None when ``kind == "none"``."""
    target: int | None
    """Index of the target in the targets given, for a target goal."""
    distance_m: float | None
    """Geodesic (FMM) length of the way to the goal, metres."""
    path_xy: list[tuple[float, float]]
    """Planned path from the robot's position to the goal, (x, y) metres, a point about every
    ``path_step_m`` (the last point is the goal); empty without a goal."""

    def to_json(self) -> dict[str, Any]:
        return {
            "goal": None if self.goal_xy is None else [round(v, 4) for v in self.goal_xy],
            "type": self.kind,
            "target": self.target,
            "distance_m": None if self.distance_m is None else round(self.distance_m, 4),
            "path": [[round(x, 4), round(y, 4)] for x, y in self.path_xy],
        }


@dataclass(frozen=True)
class DroppedTarget:
    """A target given that no robot can take as its goal."""

    target: int
    """Index of the target in the targets given."""
    xy: tuple[float, float]
    """Its position (x, y), metres."""
    reason: str
    """Why: ``"in a wall"`` (an occupied cell), ``"in unknown space"``, ``"unreachable"`` (each with no
    free cell a robot reaches within the snap distance), or ``"over the candidate limit"``
    (``candidates.max_candidates`` nearer candidates were kept)."""

    def to_json(self) -> dict[str, Any]:
        return {"x": round(self.xy[0], 4), "y": round(self.xy[1], 4), "reason": self.reason}


class Assignments(list[Assignment]):
    """The list of :func:`assign_goals`: one :class:`Assignment` per robot, and the targets given that
    cannot be a goal of any robot (:attr:`dropped_targets`)."""

    dropped_targets: list[DroppedTarget]

    def __init__(self, assignments: Sequence[Assignment] = (), dropped: Sequence[DroppedTarget] = ()) -> None:
        super().__init__(assignments)
        self.dropped_targets = list(dropped)


def dropped_targets(decision: Decision, grid: OccupancyMap, targets_xy: np.ndarray) -> list[DroppedTarget]:
    """The targets (``targets_xy``, as given to :func:`build_decision`) that no robot may take as its
    goal in ``decision``, each with the reason: where its cell lies, or the candidate limit."""
    cand = decision.candidates
    allowed = np.asarray(decision.obs["action_mask"][:, : len(cand)], dtype=bool).any(axis=0).reshape(-1)
    goal = {
        int(t): bool(ok)
        for t, ok, k in zip(cand.target_id, allowed, cand.kind, strict=True)
        if k == CandidateKind.TARGET
    }
    out = []
    cells = grid.world_to_cell(targets_xy) if len(targets_xy) else np.zeros((0, 2), dtype=np.int64)
    for t, (iy, ix) in enumerate(cells):
        if goal.get(t, False):
            continue
        if t not in goal:
            reason = "over the candidate limit"
        elif grid.occupied[iy, ix]:
            reason = "in a wall"
        elif not grid.free[iy, ix]:
            reason = "in unknown space"
        else:
            reason = "unreachable"
        out.append(DroppedTarget(t, (float(targets_xy[t, 0]), float(targets_xy[t, 1])), reason))
    return out


def _path(
    decision: Decision, r: int, goal_cell: np.ndarray, start_xy: np.ndarray, step_m: float
) -> list[tuple[float, float]]:
    """Robot ``r``'s path to ``goal_cell``: steepest descent on its FMM field from the goal (as the
    action planner reads a first path), reversed, sub-sampled every ``step_m``; from ``start_xy``."""
    routes = decision.candidates.routes
    grid = decision.grid
    assert routes is not None
    local = goal_cell - routes.box.origin
    field = routes.fields[r]
    back = descend(field / grid.cell_m, int(local[0]), int(local[1]), field.size)
    cells = back[::-1] + routes.box.origin  # robot cell ... goal cell
    if len(cells) == 0:
        cells = goal_cell[None]
    every = max(1, round(step_m / grid.cell_m))
    keep = [*range(every, len(cells) - 1, every), len(cells) - 1]
    points = [(float(start_xy[0]), float(start_xy[1]))]
    points += [(float(x), float(y)) for x, y in grid.cell_to_world(cells[keep])]
    return points


def assign_goals(
    grid: OccupancyMap | str | Path | np.ndarray,
    poses: Any,
    method: str | GoalPlanner | None = None,
    targets: Any = None,
    past_positions: Sequence[Any] | None = None,
    past_goals: Sequence[Any] | None = None,
    *,
    resolution: float | None = None,
    origin: Sequence[float] | None = None,
    config: SearchConfig | None = None,
    radius_m: float | None = None,
    sensor_range_m: float | None = None,
    seed: int = 0,
    progress: float = 0.0,
    path_step_m: float = 0.25,
    planner_settings: dict[str, Any] | None = None,
    robot_names: Sequence[str] | None = None,
) -> Assignments:
    """One goal per robot on your own (partial) map; see the module docstring.

    Args:
        grid: a ROS map YAML path, a PNG / PGM path (with ``resolution``, optional ``origin``), an
            ``OccupancyGrid``-style array (-1 unknown, 0-100; with ``resolution``, optional
            ``origin`` [x, y] or [x, y, 0]), or an :class:`OccupancyMap`.
        poses: (R, 3) x, y, yaw of the robots: metres, radians, the map frame.
        method: a registered planner name (``areasearch.planners.PLANNERS``: ``greedy``,
            ``utility``, ``voronoi``, ``coscan``, ``hungarian``, ``random``, the learned ones, the
            plug-ins; ``areasearch methods`` lists them), a planner object (reused across calls, e.g.
            a network loaded once), or None: ``greedy``, or with ``planner_settings["weights"]`` the
            learned network those weights describe.
        targets: (T, 2) x, y of known targets to cover (e.g. detected people), or None.
        past_positions, past_goals: per robot, its positions / goals at its past decisions, newest
            first, as [x, y] (a goal may be None); the learned planners use them.
        config: the settings (footprint, sensor range, candidates); ``radius_m`` and
            ``sensor_range_m`` override its robot radius and camera range.
        seed: seed of the planner's generator (same inputs and seed, same goals).
        progress: share of the mission time spent, in [0, 1] (an input of the learned planners).
        path_step_m: spacing of the path points, metres.
        planner_settings: keyword settings of a named planner (e.g. ``{"weights": "runs/x/policy"}``:
            a learned planner plays those weights, ``PREFIX.safetensors`` + ``PREFIX.json``).
        robot_names: names of the robots for error messages (default: their index).

    Returns one :class:`Assignment` per robot, in the order of ``poses`` (an :class:`Assignments`
    list, whose ``dropped_targets`` are the targets that cannot be any robot's goal, with the
    reason). Raises ConfigError or MapError, with one message naming the input at fault, on bad input.
    """
    # the arguments are checked as the command line checks its options, each error naming the argument;
    # NumPy scalars are numbers (np.float32 from a ROS message), bools, complex numbers and text are not
    cfg = config or SearchConfig()
    if not isinstance(cfg, SearchConfig):
        raise ConfigError(f"config must be an areasearch.config.SearchConfig, got {short(cfg)}")
    changes: dict[str, Any] = {}
    if radius_m is not None:
        changes["world.robot.radius_m"] = real_number("radius_m", radius_m)
    if sensor_range_m is not None:
        changes["world.camera.max_range_m"] = real_number("sensor_range_m", sensor_range_m)
    cfg = override(cfg, **changes).validate() if changes else cfg.validate()
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, (bool, np.bool_)) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {short(seed)}")
    seed = int(seed)
    path_step_m = real_number("path_step_m", path_step_m)
    if not 0 < path_step_m <= MAX_PATH_STEP_M:
        raise ConfigError(
            f"path_step_m must be a positive number of at most {MAX_PATH_STEP_M:g} m, got {path_step_m:g}"
        )
    if planner_settings is not None and not isinstance(planner_settings, Mapping):
        raise ConfigError(f"planner_settings must be a mapping of keyword settings, got {short(planner_settings)}")
    if robot_names is not None and (isinstance(robot_names, str) or not all(isinstance(n, str) for n in robot_names)):
        raise ConfigError(f"robot_names must be a list of strings, one per robot, got {short(robot_names)}")
    if (
        method is not None
        and not isinstance(method, str)
        and not (callable(getattr(method, "assign", None)) and callable(getattr(method, "reset", None)))
    ):
        raise ConfigError(
            f"method must be a planner name or a GoalPlanner (with assign and reset), got {short(method)}"
        )
    if method is None or isinstance(method, str):
        settings = dict(planner_settings or {})
        planner = choose_planner(method, settings.pop("weights", None), **settings).planner
    else:
        planner = method
    occupancy = as_occupancy(grid, resolution, origin)
    decision = build_decision(
        occupancy, poses, targets, past_positions, past_goals, config=cfg, progress=progress, robot_names=robot_names
    )
    targets_xy = _finite_rows("targets", [] if targets is None else targets, 2, "x, y in metres")
    dropped = dropped_targets(decision, occupancy, targets_xy)
    planner.reset(np.random.default_rng(seed))
    choice = np.asarray(planner.assign(decision.obs)).reshape(-1)
    poses_xy = np.asarray(poses, dtype=np.float64).reshape(-1, 3)[:, :2]
    cand = decision.candidates
    allowed = decision.obs["action_mask"][:, : len(cand)].astype(bool)
    out = []
    for r in range(len(poses_xy)):
        i = int(choice[r]) if r < len(choice) else -1
        if not (0 <= i < len(cand) and allowed[r, i]):  # a planner outside its contract: nearest allowed
            i = int(np.argmin(np.where(allowed[r], cand.distance_m[r], np.inf))) if allowed[r].any() else -1
        if i < 0:
            out.append(Assignment(r, "none", None, None, None, []))
            continue
        goal_xy = occupancy.cell_to_world(cand.cells[i])
        out.append(
            Assignment(
                robot=r,
                kind=KINDS[int(cand.kind[i])],
                goal_xy=(float(goal_xy[0]), float(goal_xy[1])),
                target=int(cand.target_id[i]) if cand.kind[i] == CandidateKind.TARGET else None,
                distance_m=float(cand.distance_m[r, i]),
                path_xy=_path(decision, r, cand.cells[i], poses_xy[r], path_step_m),
            )
        )
    return Assignments(out, dropped)


# ---------------------------------------------------------------------------------- JSON in and out


def _json_file(path: str | Path, what: str, keys: Sequence[str]) -> dict[str, Any]:
    """The JSON object of a ``what`` file (at most :attr:`~areasearch.inputs.InputLimits.max_json_bytes`)
    whose top-level keys are ``keys``, the first required; ConfigError naming the file otherwise."""
    path = Path(path).expanduser()
    data = read_bytes(path, f"{what} file", limits().max_json_bytes, LIMIT_VARIABLES["max_json_bytes"], ConfigError)
    return _json_doc(data, str(path), keys)


def _json_doc(data: bytes, path: str, keys: Sequence[str]) -> dict[str, Any]:
    """The JSON object in ``data`` (read from ``path``, named in the messages) whose top-level keys are
    ``keys``, the first required; ConfigError otherwise."""
    doc = parse_json(data, path, ConfigError)  # an integer of over 4,300 digits too: one message
    if not isinstance(doc, dict) or not isinstance(doc.get(keys[0]), list):
        raise ConfigError(f"{path}: expected an object with a {keys[0]!r} list")
    unknown = sorted(set(doc) - set(keys))
    if unknown:
        raise ConfigError(
            f"{path}: unknown top-level field(s) {', '.join(short(k, 30) for k in unknown[:5])}"
            f"{' ...' if len(unknown) > 5 else ''}; known: {', '.join(keys)}"
        )
    return doc


def _number(source: str, name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{source}: {name} must be a number, got {short(value)}")
    try:
        number = float(value)
    except OverflowError:  # an integer beyond the largest float
        raise ConfigError(f"{source}: {name} must be a finite number, got {short(value)}") from None
    if not math.isfinite(number):
        raise ConfigError(f"{source}: {name} must be a finite number, got {value!r}")
    return number


def _point(source: str, name: str, value: Any) -> list[float]:
    if not isinstance(value, list) or len(value) != 2:
        raise ConfigError(f"{source}: {name} must be an [x, y] pair of numbers, got {short(value)}")
    return [_number(source, f"{name}[{k}]", v) for k, v in enumerate(value)]


def _ids(source: str, name: str, items: list[Any], prefix: str) -> list[str]:
    ids = []
    for k, item in enumerate(items):
        value = item.get("id", f"{prefix}_{k}")
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{source}: {name}[{k}].id must be a non-empty string, got {short(value)}")
        ids.append(value)
    if len(set(ids)) != len(ids):
        seen: set[str] = set()
        dup = ids[0]
        for dup in ids:
            if dup in seen:
                break
            seen.add(dup)
        raise ConfigError(f"{source}: {name} id {short(dup)} is used twice")
    return ids


@dataclass(frozen=True)
class RobotsFile:
    """The contents of a robots JSON file (see :func:`read_robots`)."""

    ids: list[str]
    poses: np.ndarray
    """(R, 3) x, y, yaw."""
    past_positions: list[list[list[float]]] | None
    past_goals: list[list[list[float] | None]] | None


def read_robots(path: str | Path) -> RobotsFile:
    """Read a robots file: ``{"robots": [{"id": "tb3_0", "x": 1.0, "y": 2.0, "yaw": 0.0,
    "past_positions": [[x, y], ...], "past_goals": [[x, y] | null, ...]}, ...]}`` (``id``, ``yaw``
    (default 0) and the past lists (newest first) optional). ConfigError naming the entry at fault."""
    if str(path) == "-":  # `areasearch assign --robots -`: the robots JSON on standard input
        source = "standard input"
        return robots_from_json(_json_doc(_stdin_bytes("robots"), source, ("robots",))["robots"], source)
    return robots_from_json(_json_file(path, "robots", ("robots",))["robots"], str(path))


def _stdin_bytes(what: str) -> bytes:
    """The bytes of standard input, at most :attr:`~areasearch.inputs.InputLimits.max_json_bytes`
    (read one byte beyond, so a larger input is refused without being read whole)."""
    bound = limits().max_json_bytes
    if sys.stdin is None or sys.stdin.isatty():
        raise ConfigError(f"standard input is a terminal; pipe the {what} JSON in (... | areasearch assign --robots -)")
    try:
        data = sys.stdin.buffer.read(bound + 1)
    except (OSError, ValueError, AttributeError) as exc:  # closed or not a byte stream
        raise ConfigError(f"standard input: cannot read the {what} JSON ({clip(str(exc))})") from None
    if len(data) > bound:
        raise ConfigError(
            f"standard input: the {what} JSON is larger than {bound:,} bytes, the limit "
            f"(environment variable {LIMIT_VARIABLES['max_json_bytes']})"
        )
    return data


def robots_from_json(items: list[Any], source: str) -> RobotsFile:
    """The robots of a parsed robots JSON (the ``"robots"`` list of :func:`read_robots`), with its
    checks and messages, each starting with ``source`` (the file, or the request of the goal service)."""
    if not isinstance(items, list):
        raise ConfigError(f"{source}: 'robots' must be a list of robots, got {short(items)}")
    if not items:
        raise ConfigError(f"{source}: 'robots' is empty; give at least one robot")
    if len(items) > MAX_ROBOTS:
        raise ConfigError(f"{source}: {len(items)} robots; the planners plan for at most {MAX_ROBOTS}")
    poses = np.zeros((len(items), 3))
    pasts: list[list[list[float]]] = []
    goals: list[list[list[float] | None]] = []
    has_past = has_goals = False
    for k, item in enumerate(items):
        name = f"robots[{k}]"
        if not isinstance(item, dict):
            raise ConfigError(f"{source}: {name} must be an object with x, y, yaw, got {short(item)}")
        unknown = sorted(set(item) - {"id", "x", "y", "yaw", "past_positions", "past_goals"})
        if unknown:
            raise ConfigError(f"{source}: {name} has unknown field(s) {', '.join(short(k, 30) for k in unknown[:5])}")
        for j, key in enumerate(("x", "y")):
            if key not in item:
                raise ConfigError(f"{source}: {name} has no {key!r}")
            poses[k, j] = _number(source, f"{name}.{key}", item[key])
        poses[k, 2] = _number(source, f"{name}.yaw", item.get("yaw", 0.0))
        past = item.get("past_positions", [])
        gone = item.get("past_goals", [])
        if not isinstance(past, list) or not isinstance(gone, list):
            raise ConfigError(f"{source}: {name}.past_positions and past_goals must be lists of [x, y]")
        has_past |= "past_positions" in item
        has_goals |= "past_goals" in item
        pasts.append([_point(source, f"{name}.past_positions[{i}]", p) for i, p in enumerate(past)])
        goals.append([None if g is None else _point(source, f"{name}.past_goals[{i}]", g) for i, g in enumerate(gone)])
    return RobotsFile(
        _ids(source, "robots", items, "robot"), poses, pasts if has_past else None, goals if has_goals else None
    )


def read_targets(path: str | Path) -> tuple[list[str], np.ndarray]:
    """Read a targets file: ``{"targets": [{"id": "person_1", "x": 3.0, "y": 1.5}, ...]}`` (``id``
    optional). Returns (ids, (T, 2) x, y)."""
    return targets_from_json(_json_file(path, "targets", ("targets",))["targets"], str(path))


def targets_from_json(items: list[Any], source: str) -> tuple[list[str], np.ndarray]:
    """The targets of a parsed targets JSON (the ``"targets"`` list of :func:`read_targets`), with its
    checks and messages, each starting with ``source``. Returns (ids, (T, 2) x, y)."""
    if not isinstance(items, list):
        raise ConfigError(f"{source}: 'targets' must be a list of targets, got {short(items)}")
    xy = np.zeros((len(items), 2))
    for k, item in enumerate(items):
        name = f"targets[{k}]"
        if not isinstance(item, dict):
            raise ConfigError(f"{source}: {name} must be an object with x, y, got {short(item)}")
        unknown = sorted(set(item) - {"id", "x", "y"})
        if unknown:
            raise ConfigError(f"{source}: {name} has unknown field(s) {', '.join(short(k, 30) for k in unknown[:5])}")
        for j, key in enumerate(("x", "y")):
            if key not in item:
                raise ConfigError(f"{source}: {name} has no {key!r}")
            xy[k, j] = _number(source, f"{name}.{key}", item[key])
    return _ids(source, "targets", items, "target"), xy


_PAIR = re.compile(r"\[\s*(-?[0-9][0-9.eE+-]*),\s*(-?[0-9][0-9.eE+-]*)\s*\]")


def dumps(doc: Any) -> str:
    """``doc`` as indented JSON with every [x, y] pair of numbers on one line."""
    return _PAIR.sub(r"[\1, \2]", json.dumps(doc, indent=2)) + "\n"


def assignments_json(
    assignments: Sequence[Assignment],
    robot_ids: Sequence[str],
    target_ids: Sequence[str],
    method: str,
    weights: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """The JSON document ``areasearch assign`` prints: the method (and, for weights of your own,
    ``weights`` and ``weights_sha256``: :meth:`areasearch.planners.Choice.record`), one entry per
    robot and, when targets were given, ``dropped_targets``: those no robot can take as a goal, with
    the reason."""
    robots = []
    for a in assignments:
        entry = {"id": robot_ids[a.robot], **a.to_json()}
        if a.target is not None:
            entry["target"] = target_ids[a.target]
        robots.append(entry)
    doc: dict[str, Any] = {"frame": "map", "method": method, **(weights or {}), "robots": robots}
    if target_ids:
        dropped = getattr(assignments, "dropped_targets", [])
        doc["dropped_targets"] = [{"id": target_ids[d.target], **d.to_json()} for d in dropped]
    return doc


def dropped_lines(assignments: Sequence[Assignment], target_ids: Sequence[str]) -> list[str]:
    """One line per dropped target of ``assignments``, for stderr."""
    return [
        f"target {short(target_ids[d.target], 40)} at ({d.xy[0]:g}, {d.xy[1]:g}) cannot be a goal ({d.reason}); dropped"
        for d in getattr(assignments, "dropped_targets", [])
    ]
