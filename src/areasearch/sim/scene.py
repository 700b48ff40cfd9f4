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
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

from ..config import RobotConfig
from ..errors import MapError
from ..inputs import (
    LIMIT_VARIABLES,
    check_path,
    limits,
    read_bytes,
    regular_file,
    short,
)
from . import footprint
from .mapfiles import MAX_CELL_M, check_resolution, open_image, read_ros_map, read_ros_yaml

SIZE_BANDS_M2: dict[str, tuple[float, float]] = {
    "small": (0.0, 31.0),
    "medium": (36.0, 66.0),
    "large": (69.0, 1000.0),
}
"""Free-area bands of the paper's scene size classes, square metres."""

SIZE_CLASSES = tuple(SIZE_BANDS_M2)

SHARED_FREE, SHARED_OCCUPIED, SHARED_UNKNOWN = 255, 0, 127
"""Pixel values of the bundled maps' PNG format."""


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


def load_ros_yaml(path: str | Path, *, wall_height_m: float = 2.5) -> Scene:
    """Load a ROS ``map_server`` map: the YAML file and the PGM/PNG image it names.

    Reads pixels as map_server does (:func:`~areasearch.sim.mapfiles.read_map_image`): p = (255 - v) / 255
    (or v / 255 with ``negate: 1``);
    p > ``occupied_thresh`` is occupied, p < ``free_thresh`` is free, the rest unknown; a fully
    transparent pixel is unknown; 16-bit grey by its full range. ``mode: raw`` reads v directly as
    0-100 occupancy. The origin [x, y, yaw] is honoured (yaw must be 0: rotated maps are not
    supported). The YAML's checks: :func:`~areasearch.sim.mapfiles.read_ros_yaml`.
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
