"""A ROS ``nav_msgs/OccupancyGrid`` message, as rosbridge serialises it to JSON, as an occupancy map.

The goal service (:mod:`areasearch.service.serve`) takes the map of a robot stack as the stack holds it: the
``/map`` message of a ROS 2 or ROS 1 SLAM node, forwarded as rosbridge writes it::

    {"header": {"frame_id": "map", "stamp": {...}},
     "info": {"resolution": 0.05, "width": 384, "height": 384,
              "origin": {"position": {"x": -10.0, "y": -10.0, "z": 0.0},
                         "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}},
     "data": [-1, -1, 0, 100, ...]}

``data`` holds ``width * height`` cells, row-major, **row 0 at the origin** (the map's southern
edge: ``data[iy * width + ix]`` is the cell whose south-west corner is ``origin + (ix, iy) *
resolution``), exactly the layout of :func:`areasearch.service.grid.occupancy_from_array` (an image's
top row, in contrast, is the *northern* edge; :func:`areasearch.service.grid.load_occupancy` flips it).
Values: -1 unknown, 0-100 the occupancy probability in percent, read with map_server's default
thresholds (:data:`areasearch.service.grid.FREE_THRESH` 0.196 and :data:`~areasearch.service.grid.OCCUPIED_THRESH`
0.65: below 19.6 free, above 65 occupied, unknown between; a SLAM node's 0 / 100 / -1 are free /
occupied / unknown). The origin's orientation must be the identity (a yaw-0 map, as every SLAM node
publishes; an all-zero quaternion, ROS 1's default, counts as unset). ``header`` and the stamps are
optional and ignored (goals come back in the grid's frame).

Field checks are pydantic's (type and presence, one error per field, named by its path such as
``map.info.width``); the values themselves are checked by the library's own functions, so that a
resolution, an origin or a cell value is refused with the same words as a map file
(:class:`~areasearch.errors.MapError`).
"""

from __future__ import annotations

import array
import math
from dataclasses import dataclass
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, WithJsonSchema

from ..errors import MapError
from ..sim.mapfiles import check_origin, check_resolution
from .grid import FREE_THRESH, OCCUPIED_THRESH, OccupancyMap, occupancy_from_array

CELL_VALUES_SCHEMA = {
    "type": "array",
    "items": {"type": "integer", "minimum": -1, "maximum": 100},
    "description": "width * height cells, row-major, row 0 at the origin: -1 unknown, 0-100 occupancy (%)",
}
"""JSON schema of ``data`` (checked with NumPy, not item by item: a large map has millions of cells)."""


class _Lenient(BaseModel):
    """A message part: typed fields, extra fields (stamps, ``seq``, ``map_load_time``) ignored."""

    model_config = ConfigDict(strict=True, extra="ignore")


class Point(_Lenient):
    x: float
    y: float
    z: float = 0.0


class Quaternion(_Lenient):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


class Pose(_Lenient):
    position: Point
    orientation: Quaternion = Quaternion()


class MapMetaData(_Lenient):
    resolution: float = Field(description="metres per cell")
    width: int = Field(ge=1, le=2**31 - 1, description="cells along x")
    height: int = Field(ge=1, le=2**31 - 1, description="cells along y")
    origin: Pose = Field(description="map-frame pose of the south-west corner of cell (0, 0); yaw 0")


class Header(_Lenient):
    frame_id: str = "map"


class OccupancyGrid(BaseModel):
    """``nav_msgs/OccupancyGrid`` as rosbridge serialises it (``header`` optional)."""

    model_config = ConfigDict(strict=True, extra="forbid")

    header: Header | None = None
    info: MapMetaData
    data: Annotated[Any, WithJsonSchema(CELL_VALUES_SCHEMA)]


@dataclass(frozen=True)
class GridCells:
    """A checked grid: what the service stores and hands to its workers (compact: one byte a cell)."""

    cells: np.ndarray
    """(height, width) int8, row 0 at the origin: -1 unknown, 0-100 occupancy."""
    resolution: float
    origin_xy: tuple[float, float]
    source: str
    """Name of the map in messages (``map``, or ``maps/<name>`` for a stored one)."""

    def to_map(self) -> OccupancyMap:
        """The :class:`~areasearch.service.grid.OccupancyMap` (map_server's default thresholds)."""
        return occupancy_from_array(
            self.cells,
            self.resolution,
            self.origin_xy,
            free_thresh=FREE_THRESH,
            occupied_thresh=OCCUPIED_THRESH,
            source=self.source,
        )


def origin_yaw(q: Any, what: str = "map.info.origin.orientation") -> float:
    """Yaw (radians) of a map origin's orientation ``q`` (fields x, y, z, w), 0 for an all-zero quaternion
    (ROS 1's unset default); MapError, naming the field as ``what``, for one that is not finite or tilts the
    map (roll or pitch)."""
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    norm = math.hypot(x, y, z, w)  # never overflows (q.x**2 did, for 1e200)
    if not math.isfinite(norm) or norm > 1e6:
        raise MapError(f"{what} must be a quaternion of finite numbers, got norm {norm:g}")
    if norm == 0.0:
        return 0.0
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    if abs(x) > 1e-6 or abs(y) > 1e-6:
        raise MapError(f"{what}: the map is tilted (roll or pitch); give a level map")
    return 2.0 * math.atan2(z, w)


def _checked_values(data: list[Any], expected: int, source: str) -> np.ndarray:
    """``data`` (a list :func:`grid_cells`' fast pass refused) as integers, or the MapError naming the
    first entry that is not an integer; a value outside -1..100 is returned for the caller to name."""
    try:
        values = np.array(data)
    except (ValueError, OverflowError):
        values = np.array([0])  # ragged or huge entries: refused below
    if values.shape != (expected,) or values.dtype.kind not in "iu":
        bad = next((k for k, v in enumerate(data) if isinstance(v, bool) or not isinstance(v, int)), None)
        what = f"; data[{bad}] is {data[bad]!r}"[:80] if bad is not None else ""
        raise MapError(f"{source}.data must be a list of integers (-1 unknown, 0-100 occupancy){what}")
    return values


def grid_cells(msg: OccupancyGrid, source: str = "map") -> GridCells:
    """The checked cells of ``msg``: the number of cells, their values, the resolution and the origin
    (each refused with the library's message, a :class:`~areasearch.errors.MapError`); the map is
    also read once (:func:`areasearch.service.grid.occupancy_from_array`: at least 3 x 3 cells, a free cell)."""
    info = msg.info
    yaw = origin_yaw(info.origin.orientation)
    position = info.origin.position
    origin = check_origin(source, [position.x, position.y, 0.0 if abs(yaw) < 1e-9 else yaw])
    resolution = check_resolution(source, info.resolution)
    expected = info.width * info.height
    data = msg.data
    if not isinstance(data, list):
        raise MapError(f"{source}.data must be a list of integers (-1 unknown, 0-100 occupancy)")
    if len(data) != expected:
        raise MapError(
            f"{source}.data holds {len(data):,} cells; info.width x info.height is "
            f"{info.width} x {info.height} = {expected:,}"
        )
    try:
        # one C pass over the list: integers from -128 to 127 (a Python int each), else TypeError or
        # OverflowError; 3.3 M cells in about 50 ms, where NumPy's type inference took 75
        values = np.frombuffer(array.array("b", data), dtype=np.int8)
    except (TypeError, OverflowError):
        values = _checked_values(data, expected, source)
    low, high = (int(values.min()), int(values.max())) if values.size else (0, 0)
    if low < -1 or high > 100:
        k = int(np.flatnonzero((values < -1) | (values > 100))[0])
        raise MapError(
            f"{source}: cell (iy={k // info.width}, ix={k % info.width}) holds {int(values[k])}; "
            "values must be -1 or 0-100"
        )
    cells = values.astype(np.int8, copy=False).reshape(info.height, info.width)
    grid = GridCells(cells, resolution, origin, source)
    grid.to_map()  # every check of the library's reader, before the map is stored or planned on
    return grid


def grid_message(grid: OccupancyMap, frame_id: str = "map") -> dict[str, Any]:
    """``grid`` as the JSON of an ``OccupancyGrid`` message (0 free, 100 occupied, -1 unknown): what a
    ROS stack's ``/map`` looks like through rosbridge, for tests, benchmarks and example clients."""
    cells = np.full(grid.shape, -1, dtype=np.int8)
    cells[grid.free] = 0
    cells[grid.occupied] = 100
    h, w = grid.shape
    return {
        "header": {"frame_id": frame_id},
        "info": {
            "resolution": grid.cell_m,
            "width": w,
            "height": h,
            "origin": {
                "position": {"x": grid.origin_xy[0], "y": grid.origin_xy[1], "z": 0.0},
                "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
            },
        },
        "data": cells.reshape(-1).tolist(),
    }
