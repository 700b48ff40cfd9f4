"""Your own occupancy map: :class:`OccupancyMap` and its readers (a ROS ``map_server`` YAML, a PNG / PGM
image, an ``nav_msgs/OccupancyGrid``-style array) and writer (:func:`save_occupancy_yaml`).

The lowest module of the service floor: the goal call (:mod:`.assign`), the observation built from
the map (:mod:`.decision`) and the ROS message reader (:mod:`.occupancy_msg`) all read maps through
it. Frames: a map's ``origin`` is the map-frame position of the south-west corner of cell [0, 0];
grids are indexed ``[iy, ix]`` with ``iy`` growing northwards (ROS: row 0 of ``OccupancyGrid.data``
is at the origin; an image's bottom row). Cells are read as map_server reads them: free below
``free_thresh``, occupied above ``occupied_thresh``, unknown between (``OccupancyGrid`` value -1 is
unknown).
"""

from __future__ import annotations

import functools
import io
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from PIL import Image

from ..errors import MapError
from ..folderlock import write_atomic
from ..inputs import LIMIT_VARIABLES, limits
from ..sim.mapfiles import (
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
"""map_server's default thresholds on the occupancy probability p (PNGs without a YAML, arrays)."""


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
    cell_m = check_resolution(source, resolution)
    xy = check_origin(source, origin)
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
        cell_m = check_resolution(source, resolution)
        xy = check_origin(source, (0.0, 0.0) if origin is None else origin)
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
