"""Pipeline stage "scene": the ground-truth building the robots search.

A :class:`Scene` is a 2.5D world: a grid of cells (``cell_m`` metres square) where each cell is
reachable free floor or an obstacle extruded to a height (walls ``wall_height_m``, furniture
lower). Grids are indexed ``[iy, ix]`` with ``iy`` growing northwards (the ROS map frame: row 0
is the southern edge, the image's bottom row); cell ``[iy, ix]`` covers
``x in origin_x + [ix, ix+1) * cell_m`` and ``y in origin_y + [iy, iy+1) * cell_m``.

Sources of scenes (:func:`scene_source` resolves a user's ``map=`` argument):

* bundled real maps (``areasearch maps`` lists them), in the package's ``maps/`` folder with their
  ``index.json`` and license notes (``maps/README.md``);
* a PNG inside a folder of that format (8-bit grayscale, 255 free / 0 occupied / 127 unknown,
  resolution from ``index.json``), or the folder itself (one map drawn per reset);
* a ROS ``map_server`` YAML file with its PGM/PNG image (``image``, ``resolution``, ``origin``,
  ``negate``, ``occupied_thresh``, ``free_thresh``, optional ``mode``), read as map_server does;
* ``procedural:<small|medium|large>``: a seeded generated layout (:mod:`areasearch.sim.layouts`).

Only the largest 4-connected free component is the map's floor: other free cells and unknown cells
become walls. The part of that floor a robot can reach is :meth:`Scene.reachable_floor` (the free
cells the footprint reaches from the team's region, :meth:`Scene.reachable`, by the world's collision
rule): floor behind a doorway narrower than the footprint, or in a corner the footprint cannot get
into, is not part of the scene; Explo %, target placement, start poses and the size class all use
it. Size classes follow the paper's free-area bands (small 0-31 m², medium 36-66 m², large
69-1000 m²; gaps go to the nearer band), applied to the reachable floor of the default robot.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from PIL import Image, UnidentifiedImageError
from scipy import ndimage

from ..config import RobotConfig
from ..errors import MapError
from ..inputs import (
    LIMIT_VARIABLES,
    check_image_size,
    check_path,
    clip,
    is_finite_real,
    limits,
    load_yaml,
    read_bytes,
    regular_file,
    short,
)
from . import footprint

SIZE_BANDS_M2: dict[str, tuple[float, float]] = {
    "small": (0.0, 31.0),
    "medium": (36.0, 66.0),
    "large": (69.0, 1000.0),
}
"""Free-area bands of the paper's scene size classes, square metres."""

SIZE_CLASSES = tuple(SIZE_BANDS_M2)

SHARED_FREE, SHARED_OCCUPIED, SHARED_UNKNOWN = 255, 0, 127
"""Pixel values of the bundled maps' PNG format."""

MAX_CELL_M = 10.0
"""Coarsest accepted map resolution, metres per cell."""

MIN_CELL_M = 0.001
"""Finest accepted map resolution, metres per cell (1 mm)."""

MAX_ORIGIN_M = 1e7
"""Largest accepted absolute map origin coordinate, metres (10,000 km: UTM northings fit)."""

LOSSLESS_FORMATS = ("PNG", "PPM", "BMP", "GIF", "TIFF")
"""Image formats read as maps (by the file's content, not its name): lossless ones only, since a
lossy format (JPEG, WebP...) turns the exact free / occupied / unknown grey levels into others."""

ROS_REQUIRED_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")
"""Keys map_server refuses to load without."""


def size_class_of(free_area_m2: float) -> str:
    """Size class of a scene from its reachable free area, by the paper's bands.

    An area between two bands goes to the nearer band (cuts at 33.5 and 67.5 m²); areas above
    1000 m² are ``large``.
    """
    if not math.isfinite(free_area_m2) or free_area_m2 < 0:
        raise MapError(f"free area must be a finite non-negative number, got {free_area_m2!r}")
    best, best_gap = "large", math.inf
    for name, (lo, hi) in SIZE_BANDS_M2.items():
        gap = 0.0 if lo <= free_area_m2 <= hi else min(abs(free_area_m2 - lo), abs(free_area_m2 - hi))
        if gap < best_gap:
            best, best_gap = name, gap
    return best


def largest_component(free: np.ndarray) -> np.ndarray:
    """Mask of the largest 4-connected component of ``free`` (all False if there is none)."""
    labels, count = ndimage.label(free)
    if count == 0:
        return np.zeros_like(free, dtype=bool)
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return labels == int(np.argmax(sizes))


@dataclass(frozen=True, eq=False)
class Scene:
    """A ground-truth 2.5D building. Build one with :func:`scene_from_grid` or a loader."""

    name: str
    """Identifier (bundled map id, file stem, or ``procedural:<class>:<seed draw>``)."""
    free: np.ndarray
    """(H, W) bool: reachable free floor (the largest 4-connected free component)."""
    height_m: np.ndarray
    """(H, W) float32: obstacle height in metres; 0 exactly where ``free``."""
    cell_m: float
    """Cell size, metres."""
    origin_xy: tuple[float, float] = (0.0, 0.0)
    """Map-frame coordinates of the south-west corner of cell [0, 0], metres (ROS ``origin``)."""
    source: str = ""
    """Where the scene came from (file path or generator)."""
    meta: dict[str, Any] = field(default_factory=dict, repr=False)
    """The map's index entry, when it has one (license, source repository...)."""
    _cache: dict[Any, Any] = field(default_factory=dict, repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.free.shape[0]), int(self.free.shape[1]))

    @property
    def content_sha256(self) -> str:
        """SHA-256 (hex) of what the map is: its shape, cell size, origin, free cells and obstacle cells,
        whatever file it was read from. An evaluation pins it in its ``config.json``, so that a map
        image edited since its episodes were played is noticed on a resume."""
        if "content_sha256" not in self._cache:
            digest = hashlib.sha256()
            digest.update(
                json.dumps([list(self.shape), float(self.cell_m), [float(v) for v in self.origin_xy]]).encode()
            )
            digest.update(np.packbits(np.ascontiguousarray(self.free, dtype=bool)).tobytes())
            digest.update(np.packbits(np.ascontiguousarray(self.height_m > 0)).tobytes())
            self._cache["content_sha256"] = digest.hexdigest()
        return str(self._cache["content_sha256"])

    @property
    def free_area_m2(self) -> float:
        """Area of the map's free floor (:attr:`free`), square metres, reachable by a robot or not."""
        return float(self.free.sum()) * self.cell_m**2

    @property
    def size_class(self) -> str:
        """Size class of the scene for the default robot (``RobotConfig().radius_m``): by the area of
        its :meth:`reachable_floor`; :meth:`size_class_for` for another footprint."""
        return self.size_class_for(RobotConfig().radius_m)

    def size_class_for(self, radius_m: float) -> str:
        """Size class by the paper's bands of the floor a robot of this radius reaches."""
        return size_class_of(self.reachable_area_m2(radius_m))

    def reachable_area_m2(self, radius_m: float | None = None) -> float:
        """Area of :meth:`reachable_floor`, square metres (default: the default robot's radius)."""
        return float(self.reachable_floor(radius_m).sum()) * self.cell_m**2

    def traversable(self, radius_m: float) -> np.ndarray:
        """(H, W) bool: cells whose centre a robot of this radius may stand on: the footprint disc
        overlaps no obstacle cell (each the square it covers; :mod:`areasearch.sim.footprint`)."""
        key = ("traversable", radius_m)
        if key not in self._cache:
            self._cache[key] = footprint.traversable(~self.free, self.cell_m, radius_m)
        return self._cache[key]

    def reachable(self, radius_m: float) -> np.ndarray:
        """(H, W) bool: the team's region, the largest set of :meth:`traversable` cells joined by
        moves between neighbouring centres (8-neighbours) that the world lets the footprint make
        (:func:`areasearch.sim.footprint.team_region`).

        Robots start there and can reach every part of it; targets are placed where a robot in
        this region can come within the cover radius.
        """
        key = ("reachable", radius_m)
        if key not in self._cache:
            self._cache[key] = footprint.team_region(~self.free, self.cell_m, radius_m)
        return self._cache[key]

    def reachable_floor(self, radius_m: float | None = None) -> np.ndarray:
        """(H, W) bool: the scene's reachable space, the free cells the footprint of a robot of this
        radius covers when its centre stands on a cell of the team's region (:meth:`reachable`), by
        the world's collision rule (:mod:`areasearch.sim.footprint`): exactly the free cells on which an
        obstacle would be in the way of a pose the team can take. Floor behind a doorway the
        footprint cannot pass is not in it (only the first ``radius`` of the doorway is), nor the
        cells deepest in a corner (a few per corner). Default radius: the default robot's
        (``RobotConfig().radius_m``).
        """
        radius = RobotConfig().radius_m if radius_m is None else float(radius_m)
        key = ("reachable_floor", radius)
        if key not in self._cache:
            self._cache[key] = self.free & footprint.covered(self.reachable(radius), self.cell_m, radius)
        return self._cache[key]

    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) map-frame metres (x, y) -> (..., 2) integer cell indices (iy, ix); may lie outside."""
        yx = np.asarray(xy, dtype=np.float64)[..., ::-1]
        return np.floor((yx - (self.origin_xy[1], self.origin_xy[0])) / self.cell_m).astype(np.int64)

    def cell_to_world(self, cells: np.ndarray) -> np.ndarray:
        """(..., 2) cell indices (iy, ix) -> (..., 2) map-frame metres of the cell centres (x, y)."""
        xy = np.asarray(cells, dtype=np.float64)[..., ::-1]
        return self.origin_xy + (xy + 0.5) * self.cell_m


def scene_from_grid(
    name: str,
    free: np.ndarray,
    cell_m: float,
    *,
    origin_xy: tuple[float, float] = (0.0, 0.0),
    wall_height_m: float = 2.5,
    height_m: np.ndarray | None = None,
    source: str = "",
    meta: dict[str, Any] | None = None,
) -> Scene:
    """Make a :class:`Scene` from a free-space mask (``[iy, ix]``, y northwards).

    Keeps only the largest 4-connected free component; every other cell becomes an obstacle of
    ``height_m`` (when given, e.g. furniture of a generated layout) or of ``wall_height_m``.
    """
    free = np.asarray(free, dtype=bool)
    if free.ndim != 2 or free.shape[0] < 3 or free.shape[1] < 3:
        raise MapError(f"{name}: a map must be a 2-D grid of at least 3x3 cells, got shape {free.shape}")
    if not (isinstance(cell_m, (int, float)) and math.isfinite(cell_m) and 0 < cell_m <= MAX_CELL_M):
        raise MapError(f"{name}: resolution must be in (0, {MAX_CELL_M}] metres per cell, got {cell_m!r}")
    if not (wall_height_m > 0):
        raise MapError(f"{name}: wall height must be positive, got {wall_height_m!r}")
    reach = largest_component(free)
    if not reach.any():
        raise MapError(f"{source or name}: the map has no free cell")
    # Seal the border: a free cell on the edge of the grid would let rays leave the map.
    if reach[0].any() or reach[-1].any() or reach[:, 0].any() or reach[:, -1].any():
        reach = np.pad(reach, 1)
        if height_m is not None:
            height_m = np.pad(np.asarray(height_m, np.float32), 1, constant_values=wall_height_m)
        origin_xy = (origin_xy[0] - cell_m, origin_xy[1] - cell_m)
    heights = np.full(reach.shape, wall_height_m, dtype=np.float32)
    if height_m is not None:
        given = np.asarray(height_m, dtype=np.float32)
        if given.shape != reach.shape:
            raise MapError(f"{name}: height grid shape {given.shape} differs from map shape {reach.shape}")
        heights = np.where(given > 0, given, heights).astype(np.float32)
    heights[reach] = 0.0
    return Scene(
        name=name,
        free=reach,
        height_m=heights,
        cell_m=float(cell_m),
        origin_xy=(float(origin_xy[0]), float(origin_xy[1])),
        source=source,
        meta=dict(meta or {}),
    )


# ---------------------------------------------------------------------------------- image files


def open_image(path: Path) -> Image.Image:
    """The image file at ``path``, fully read into memory (the file is closed again); MapError when
    it is missing or not a regular file, larger than the limits (:class:`areasearch.inputs.InputLimits`:
    the file's bytes, and the cells and decoded bytes its header declares, checked before any pixel
    is decoded), not an image PIL can read, or in a lossy format (by its content, whatever its name
    says: :data:`LOSSLESS_FORMATS`)."""
    path = Path(path)
    info = regular_file(path, "map image", MapError)
    bound = limits()
    if info.st_size > bound.max_image_bytes:
        raise MapError(
            f"{path}: map image is larger than {bound.max_image_bytes:,} bytes, the limit "
            f"(environment variable {LIMIT_VARIABLES['max_image_bytes']})"
        )
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            opened_image = Image.open(path)  # reads the header only
        with opened_image as opened:
            check_image_size(path, opened.size, opened.mode, MapError)
            kind = opened.format or "unknown"
            compression = str(opened.info.get("compression", ""))
            if kind not in LOSSLESS_FORMATS or "jpeg" in compression or "webp" in compression:
                named = os.path.splitext(path.name)[1]
                said = f", though its name ends in {named}" if named and named[1:].upper() not in (kind, "PGM") else ""
                raise MapError(
                    f"{path}: a {kind} image by its content{said}; lossy formats turn the exact free / occupied / "
                    "unknown grey levels into others, so maps are read from PNG, PGM, BMP, GIF or TIFF only"
                )
            opened.load()
            image = opened.copy()
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        declared = re.search(r"\((\d+) pixels\)", str(exc))
        pixels = f"{int(declared.group(1)):,} pixels" if declared else "more pixels than PIL opens"
        raise MapError(
            f"{path}: the image declares {pixels}, more than the limit of {limits().max_map_cells:,} map cells "
            f"(environment variable {LIMIT_VARIABLES['max_map_cells']})"
        ) from None
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError, EOFError) as exc:
        raise MapError(f"{path}: not a readable image ({clip(str(exc))})") from None
    return image


SIXTEEN_BIT_MODES = ("I", "I;16", "I;16B", "I;16L")
"""Image modes of 16-bit greyscale (PIL opens a PGM whose maxval is over 255 as ``I``, scaled to
0-65535 by its maxval; a 16-bit PNG as ``I;16``)."""


def grey_levels(image: Image.Image, source: str = "image") -> np.ndarray:
    """(H, W) float64 grey levels of ``image`` on the 8-bit scale 0-255: 8-bit grey as it is, colour
    and palette images as their luminance, 16-bit grey (:data:`SIXTEEN_BIT_MODES`) by its full
    scale (v * 255 / 65535: a PGM by its maxval, so a 16-bit map reads as its 8-bit twin)."""
    if image.mode in SIXTEEN_BIT_MODES:
        value = np.asarray(image).astype(np.float64)
        if value.size and (value.min() < 0 or value.max() > 65535):
            raise MapError(f"{source}: a 32-bit image (values outside 0-65535); use 8- or 16-bit grey")
        return value * (255.0 / 65535.0)
    if image.mode == "F":
        raise MapError(f"{source}: a floating-point image; use 8- or 16-bit grey")
    return np.asarray(image.convert("L")).astype(np.float64)


def read_map_image(
    image: Image.Image, mode: str, negate: bool, free_thresh: float, occupied_thresh: float, source: str = "image"
) -> tuple[np.ndarray, np.ndarray]:
    """(free, occupied) (H, W) bool cells of a map image read as ROS ``map_server`` reads it, rows
    flipped so that row 0 is the image's bottom row (the map frame's south).

    ``mode`` ``"trinary"`` or ``"scale"`` (the same cells: both split at the thresholds): a pixel of
    grey value v (colour and palette images are read as grey) has occupancy p = (255 - v) / 255, or
    v / 255 with ``negate``; p < ``free_thresh`` is free, p > ``occupied_thresh`` occupied.
    16-bit grey is read on the 8-bit scale by its full range (:func:`grey_levels`).
    ``"raw"``: v itself is the occupancy in percent (``negate`` ignored; 8-bit images only); v <=
    ``free_thresh`` * 100 is free, ``occupied_thresh`` * 100 <= v <= 100 occupied. Either way the rest
    is unknown, and so is a fully transparent pixel (an image with an alpha channel or a transparent palette entry).
    A cell is never both free and occupied when ``free_thresh < occupied_thresh``.
    """
    if mode not in ("trinary", "scale", "raw"):
        raise ValueError(f"mode must be trinary, scale or raw, got {mode!r}")
    if mode == "raw" and image.mode in SIXTEEN_BIT_MODES:
        raise MapError(f"{source}: mode raw reads 8-bit occupancy values 0-100; this image is 16-bit")
    alpha = None
    if image.mode in ("LA", "RGBA") or (image.mode == "P" and "transparency" in image.info):
        alpha = np.asarray(image.convert("RGBA"))[..., 3]
    if mode == "raw":
        value = np.asarray(image.convert("I") if image.mode != "L" else image).astype(np.float64)
        free = value <= free_thresh * 100.0
        occupied = (value >= occupied_thresh * 100.0) & (value <= 100.0)
    else:
        value = grey_levels(image, source)
        p = value / 255.0 if negate else (255.0 - value) / 255.0
        free = p < free_thresh
        occupied = p > occupied_thresh
    if alpha is not None:
        free &= alpha > 0
        occupied &= alpha > 0
    return np.flipud(free), np.flipud(occupied)


def load_png(
    path: str | Path, cell_m: float, *, wall_height_m: float = 2.5, meta: dict[str, Any] | None = None
) -> Scene:
    """Load a map in the bundled maps' format: 8-bit grayscale, 255 free, 0 occupied, 127 unknown.

    Unknown cells (outside the building) become walls. ``cell_m`` is the resolution in metres.
    """
    path = Path(path)
    image = open_image(path)
    if image.mode != "L":
        raise MapError(f"{path}: expected an 8-bit grayscale PNG (mode 'L'), got mode {image.mode!r}")
    pixels = np.asarray(image)
    free = np.flipud(pixels == SHARED_FREE)
    name = (meta or {}).get("id", path.stem)
    return scene_from_grid(name, free, cell_m, wall_height_m=wall_height_m, source=str(path), meta=meta)


@dataclass(frozen=True)
class RosMap:
    """The fields of a ROS ``map_server`` YAML file, checked (:func:`read_ros_yaml`)."""

    path: Path
    """The YAML file."""
    image: Path
    """The map image, resolved against the YAML's folder."""
    resolution: float
    """Metres per cell, in [:data:`MIN_CELL_M`, :data:`MAX_CELL_M`]."""
    origin_xy: tuple[float, float]
    """Map-frame (x, y) of the image's lower-left corner, metres (yaw 0), within :data:`MAX_ORIGIN_M`."""
    negate: bool
    occupied_thresh: float
    free_thresh: float
    mode: str
    """``trinary``, ``scale`` or ``raw``."""


def _yaml_number(path: Path, data: dict[str, Any], key: str) -> float:
    value = data[key]
    if not is_finite_real(value):
        raise MapError(f"{path}: field {key!r} must be a number, got {short(value)}")
    return float(value)


def check_thresholds(source: str, free_thresh: Any, occupied_thresh: Any, prefix: str = "") -> tuple[float, float]:
    """(free_thresh, occupied_thresh) as floats with 0 <= free_thresh < occupied_thresh <= 1 (shares of
    occupancy, as ROS's map_server reads them), or MapError naming ``source``: a threshold above 1 made
    every cell free, a NaN none."""
    values = []
    for name, value in (("free_thresh", free_thresh), ("occupied_thresh", occupied_thresh)):
        if not is_finite_real(value):
            raise MapError(f"{source}: {prefix}{name} must be a number from 0 to 1, got {short(value)}")
        values.append(float(value))
    free, occupied = values
    if not 0.0 <= free < occupied <= 1.0:
        raise MapError(
            f"{source}: need 0 <= {prefix}free_thresh < {prefix}occupied_thresh <= 1, got free_thresh={free:g}, "
            f"occupied_thresh={occupied:g}"
        )
    return free, occupied


def check_resolution(source: str, resolution: Any, what: str = "resolution") -> float:
    """``resolution`` as a float in [:data:`MIN_CELL_M`, :data:`MAX_CELL_M`] metres per cell, or MapError
    (NumPy numbers are numbers: ``np.float32`` from a ROS message works)."""
    if not is_finite_real(resolution):
        raise MapError(f"{source}: {what} must be a number of metres per cell, got {short(resolution)}")
    if not MIN_CELL_M <= resolution <= MAX_CELL_M:
        raise MapError(
            f"{source}: {what} must be in [{MIN_CELL_M}, {MAX_CELL_M}] metres per cell, got {short(resolution)}"
        )
    return float(resolution)


def check_origin(source: str, origin: Any, what: str = "origin") -> tuple[float, float]:
    """``origin`` [x, y] or [x, y, yaw] (yaw 0) as (x, y), each finite and within :data:`MAX_ORIGIN_M`
    metres, or MapError."""
    values = list(origin) if isinstance(origin, (list, tuple, np.ndarray)) else None
    if values is None or len(values) not in (2, 3) or not all(is_finite_real(v) for v in values):
        raise MapError(f"{source}: {what} must be a list of numbers [x, y, yaw] (yaw 0), got {short(origin)}")
    if len(values) == 3 and abs(float(values[2])) > 1e-9:
        raise MapError(f"{source}: {what} has yaw {short(values[2])}; rotated maps are not supported (use yaw 0)")
    if any(abs(float(v)) > MAX_ORIGIN_M for v in values[:2]):
        raise MapError(
            f"{source}: {what} ({float(values[0]):g}, {float(values[1]):g}) lies farther than {MAX_ORIGIN_M:g} m "
            "from the frame's zero; shift the map frame"
        )
    return float(values[0]), float(values[1])


def read_ros_yaml(path: str | Path) -> RosMap:
    """The checked fields of a ROS ``map_server`` YAML file; MapError naming the file and the field.

    The file is at most :attr:`areasearch.inputs.InputLimits.max_yaml_bytes` long and is parsed
    without anchors and aliases (:func:`areasearch.inputs.load_yaml`); numbers are read as map_server
    reads them (``1e6`` is a number); every field that must be a scalar is one.
    """
    path = Path(path)
    data_bytes = read_bytes(path, "map YAML", limits().max_yaml_bytes, LIMIT_VARIABLES["max_yaml_bytes"], MapError)
    try:
        data = load_yaml(data_bytes.decode("utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise MapError(f"{path}: not valid YAML ({clip(str(exc))})") from None
    except RecursionError:
        raise MapError(f"{path}: not valid YAML (nested too deeply)") from None
    if not isinstance(data, dict):
        raise MapError(f"{path}: a map YAML must be a mapping with keys {', '.join(ROS_REQUIRED_KEYS)}")
    missing = [key for key in ROS_REQUIRED_KEYS if key not in data]
    if missing:
        raise MapError(f"{path}: missing required field(s) {', '.join(missing)}")
    if not isinstance(data["image"], str) or not data["image"]:
        raise MapError(f"{path}: field 'image' must be a file name, got {short(data['image'])}")
    check_path(data["image"], f"{path}: field 'image'", MapError)  # a NUL byte, a name over 255 bytes
    resolution = check_resolution(str(path), data["resolution"], "field 'resolution'")
    if not isinstance(data["origin"], (list, tuple)) or len(data["origin"]) != 3:
        raise MapError(
            f"{path}: field 'origin' must be a list of three numbers [x, y, yaw], got {short(data['origin'])}"
        )
    origin = check_origin(str(path), data["origin"], "field 'origin'")
    negate = data["negate"]
    if isinstance(negate, float) or negate not in (0, 1, True, False):
        raise MapError(f"{path}: field 'negate' must be 0 or 1, got {short(negate)}")
    occupied_thresh = _yaml_number(path, data, "occupied_thresh")
    free_thresh = _yaml_number(path, data, "free_thresh")
    if not 0.0 <= free_thresh < occupied_thresh <= 1.0:
        raise MapError(
            f"{path}: need 0 <= free_thresh < occupied_thresh <= 1, got free_thresh={free_thresh}, "
            f"occupied_thresh={occupied_thresh}"
        )
    mode = data.get("mode", "trinary")
    if mode not in ("trinary", "scale", "raw"):
        raise MapError(f"{path}: field 'mode' must be trinary, scale or raw, got {short(mode)}")
    image_path = Path(data["image"])
    if not image_path.is_absolute():
        image_path = path.parent / image_path
    return RosMap(path, image_path, resolution, origin, bool(negate), occupied_thresh, free_thresh, str(mode))


MAP_IMAGE_MODES = ("1", "L", "LA", "P", "RGB", "RGBA", *SIXTEEN_BIT_MODES)
"""Image modes read as maps: 1-bit, 8- and 16-bit grey (with alpha), palette, colour."""


def read_ros_map(ros: RosMap) -> tuple[np.ndarray, np.ndarray]:
    """(free, occupied) (H, W) bool cells of a ROS map's image (:func:`read_map_image`), row 0 south."""
    image = open_image(ros.image)
    if image.mode not in MAP_IMAGE_MODES:
        raise MapError(f"{ros.image}: unsupported image mode {image.mode!r}")
    return read_map_image(image, ros.mode, ros.negate, ros.free_thresh, ros.occupied_thresh, str(ros.image))


def load_ros_yaml(path: str | Path, *, wall_height_m: float = 2.5) -> Scene:
    """Load a ROS ``map_server`` map: the YAML file and the PGM/PNG image it names.

    Reads pixels as map_server does (:func:`read_map_image`): p = (255 - v) / 255 (or v / 255 with ``negate: 1``);
    p > ``occupied_thresh`` is occupied, p < ``free_thresh`` is free, the rest unknown; a fully
    transparent pixel is unknown; 16-bit grey by its full range. ``mode: raw`` reads v directly as
    0-100 occupancy. The origin [x, y, yaw] is honoured (yaw must be 0: rotated maps are not
    supported). The YAML's checks: :func:`read_ros_yaml`.
    """
    ros = read_ros_yaml(path)
    # occupied and unknown cells are both walls of the scene
    free, _ = read_ros_map(ros)
    meta = {"id": ros.path.stem, "ros_yaml": str(ros.path), "mode": ros.mode}
    return scene_from_grid(
        ros.path.stem,
        free,
        ros.resolution,
        origin_xy=ros.origin_xy,
        wall_height_m=wall_height_m,
        source=str(ros.path),
        meta=meta,
    )


# ---------------------------------------------------------------------------------- map folders


def _read_index(folder: Path) -> dict[str, Any]:
    index_path = folder / "index.json"
    if not os.path.lexists(index_path):
        raise MapError(f"{folder}: no index.json (a map folder needs one; see the bundled maps/README.md)")
    data = read_bytes(index_path, "map index", limits().max_json_bytes, LIMIT_VARIABLES["max_json_bytes"], MapError)
    try:
        index = json.loads(data.decode("utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise MapError(f"{index_path}: not valid JSON ({exc})") from None
    if not isinstance(index, dict) or not isinstance(index.get("maps"), list):
        raise MapError(f"{index_path}: expected an object with a 'maps' list")
    if not isinstance(index.get("format", {}), dict):
        raise MapError(f"{index_path}: 'format' must be an object")
    for entry in index["maps"]:
        if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
            raise MapError(f"{index_path}: every entry of 'maps' needs a 'file' name")
        res = entry.get("resolution_m_per_px", index.get("format", {}).get("resolution_m_per_px"))
        if isinstance(res, bool) or not isinstance(res, (int, float)) or not res > 0:
            raise MapError(f"{index_path}: entry {short(entry.get('file'))} has no positive 'resolution_m_per_px'")
        check_resolution(str(index_path), res, f"entry {short(entry.get('file'))}: 'resolution_m_per_px'")
    return index


def _load_index_entry(folder: Path, index: dict[str, Any], entry: dict[str, Any], wall_height_m: float) -> Scene:
    res = entry.get("resolution_m_per_px", index.get("format", {}).get("resolution_m_per_px"))
    return load_png(folder / entry["file"], float(res), wall_height_m=wall_height_m, meta=entry)


def bundled_maps_dir() -> Path:
    """Folder of the maps shipped inside the package."""
    return Path(str(resources.files("areasearch") / "maps"))


def bundled_index() -> list[dict[str, Any]]:
    """Index entries of the bundled maps (id, file, size_class, free_area_m2, license, ...)."""
    return list(_read_index(bundled_maps_dir())["maps"])


# ---------------------------------------------------------------------------------- map= specs


class SceneSource:
    """What a user's ``map=`` argument resolves to: a way to draw a :class:`Scene` from an rng.

    A single map always gives the same scene (loaded once, cached); a folder draws one of its maps
    per reset; ``procedural:<class>`` generates a new layout per reset. All draws use the rng
    given, so the same seed gives the same scene.
    """

    def __init__(self, spec: str, names: Sequence[str], loader: Any, wall_height_m: float) -> None:
        self.spec = spec
        self.names = list(names)
        self._loader = loader
        self._wall_height_m = wall_height_m
        self._cache: dict[str, Scene] = {}

    def sample(self, rng: np.random.Generator) -> Scene:
        if self.spec.startswith("procedural:"):
            return self._loader(rng)
        name = self.names[0] if len(self.names) == 1 else self.names[int(rng.integers(len(self.names)))]
        if name not in self._cache:
            self._cache[name] = self._loader(name)
        return self._cache[name]

    def __repr__(self) -> str:
        return f"SceneSource({self.spec!r}, {len(self.names)} map(s))"


def _folder_source(spec: str, folder: Path, only: str | None, wall_height_m: float) -> SceneSource:
    index = _read_index(folder)
    entries = {entry["file"]: entry for entry in index["maps"]}
    if only is not None:
        if only not in entries:
            raise MapError(f"{folder / only}: not listed in {folder / 'index.json'}")
        chosen = [only]
    else:
        chosen = [name for name in entries if (folder / name).is_file()]
        if not chosen:
            raise MapError(f"{folder}: index.json lists no map file that exists")
    return SceneSource(
        spec, chosen, lambda name: _load_index_entry(folder, index, entries[name], wall_height_m), wall_height_m
    )


def scene_source(spec: str | Path | Scene, *, wall_height_m: float = 2.5) -> SceneSource:
    """Resolve a ``map=`` argument.

    Accepts a bundled map id (``areasearch maps``), ``procedural:small|medium|large``, a PNG inside
    a folder with ``index.json``, such a folder, or a ROS map YAML file. Raises :class:`MapError`
    naming the path when it cannot be used.
    """
    if isinstance(spec, Scene):
        scene = spec
        return SceneSource(scene.name, [scene.name], lambda _name: scene, wall_height_m)
    text = str(spec)
    if text.startswith("procedural:"):
        size_class = text.split(":", 1)[1]
        if size_class not in SIZE_BANDS_M2:
            raise MapError(f"{text}: unknown size class {size_class!r}; use one of {', '.join(SIZE_CLASSES)}")
        from .layouts import generate_layout

        def generate(rng: np.random.Generator) -> Scene:
            layout = generate_layout(size_class, rng, wall_height_m=wall_height_m)
            return scene_from_grid(
                text, layout.free, layout.cell_m, wall_height_m=wall_height_m, height_m=layout.height_m, source=text
            )

        return SceneSource(text, [text], generate, wall_height_m)
    bundled = bundled_maps_dir()
    path = check_path(Path(text).expanduser(), "map path", MapError)  # a NUL byte, a name over 255 bytes
    if not path.exists():
        if os.path.lexists(path):  # a symbolic link loop or a broken link: say which
            regular_file(path, "map YAML" if path.suffix.lower() in (".yaml", ".yml") else "map", MapError)
        ids = {entry["id"]: entry["file"] for entry in bundled_index()}
        if text in ids:
            return _folder_source(text, bundled, ids[text], wall_height_m)
        if path.suffix or "/" in text or "\\" in text:
            raise MapError(f"{text}: no such file or folder")
        raise MapError(f"{text}: not a bundled map id (see `areasearch maps`) nor an existing path")
    if path.is_dir():
        return _folder_source(text, path, None, wall_height_m)
    if path.suffix.lower() in (".yaml", ".yml"):
        return SceneSource(text, [text], lambda _name: load_ros_yaml(path, wall_height_m=wall_height_m), wall_height_m)
    if path.suffix.lower() == ".png":
        return _folder_source(text, path.parent, path.name, wall_height_m)
    raise MapError(
        f"{text}: expected a bundled map id, a folder with index.json, a .png in such a folder or a ROS .yaml"
    )


def load_scene(
    spec: str | Path | Scene, rng: np.random.Generator | None = None, *, wall_height_m: float = 2.5
) -> Scene:
    """Load one scene from a ``map=`` argument (draws with ``rng`` for folders and procedural maps)."""
    return scene_source(spec, wall_height_m=wall_height_m).sample(rng if rng is not None else np.random.default_rng(0))
