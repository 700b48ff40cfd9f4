"""Map files on disk: image files read as occupancy grids and ROS ``map_server`` YAML files, with
the checks every map input passes (sizes, resolution, origin, thresholds).

:func:`open_image` reads an image file within the input limits (lossless formats only);
:func:`read_map_image` turns its pixels into free / occupied cells as map_server does;
:func:`read_ros_yaml` reads and checks a map YAML (:class:`RosMap`) and :func:`read_ros_map` its
image. :mod:`areasearch.sim.scene` builds scenes from them (``load_png``, ``load_ros_yaml``); the
service reads users' maps with them. Errors are :class:`~areasearch.errors.MapError` naming the file.

Units: resolution metres per cell, origin metres; grids ``[iy, ix]`` with row 0 the southern edge.
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from PIL import Image, UnidentifiedImageError

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
