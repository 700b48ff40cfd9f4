"""Seeded procedural generator of indoor floor layouts (pipeline stage "scene").

This module provides procedural layouts for training variety: each call to
:func:`generate_layout` draws a new floor plan (offices from a recursive binary
space partition, a corridor with rooms on both sides, or an open plan with
partition walls), connects the rooms with doors and scatters a few furniture
blocks inside them (the room plans and doors: :mod:`areasearch.sim.rooms`; the
partition walls and furniture: :mod:`areasearch.sim.furnish`).  Rooms have
sides of roughly 2.2-7 m (open-plan zones up to 14 m), walls are 1-3 cells
thick, doors 0.8-1.2 m wide and furniture blocks 0.4-1.5 m per side and
0.4-1.0 m high (tall enough for the camera to see from any robot pose).

Size classes
    The free floor area of a layout falls inside the band of the requested size
    class.  The bands follow the DA-HGNN paper (small 0-31 m², medium 36-66 m²,
    large 69-1000 m²); :data:`SIZE_BANDS_M2` stores them verbatim.  In practice
    the generator keeps small layouts at >= 10 m² and large layouts at <= 400 m²
    so that they stay meaningful and fast to simulate.

Units
    Lengths and heights are in metres, areas in square metres.  ``cell_m`` is
    the edge length of one square grid cell.

Coordinate convention
    ``free[row, col]``: the row index is ``y`` and the column index is ``x``.
    Row 0 is the SOUTH (bottom) edge of the map and ``y`` grows with the row
    index; column 0 is the WEST edge and ``x`` grows with the column index.
    The centre of cell ``(row, col)`` is at ``((col + 0.5) * cell_m,
    (row + 0.5) * cell_m)``.

Guarantees
    * all free cells form ONE 4-connected component;
    * the outer boundary is wall and every side has a non-free margin of at
      least two cells;
    * every door is at least 0.8 m wide, so that the configuration space of a
      robot of radius 0.18 m (free cells whose distance to the nearest non-free
      cell exceeds 0.18 m + half a cell) is one 8-connected component;
    * ``height_m`` is 0.0 on free cells, ``wall_height_m`` on walls and in
      [0.4, 1.0] on furniture;
    * the same generator state gives the same layout, bit for bit: all the
      randomness comes from the ``rng`` argument.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy import ndimage

from .furnish import EIGHT, FOUR, Grid, add_furniture, add_partitions, cspace_of
from .rooms import (
    Edge,
    LayoutParams,
    Rect,
    Room,
    drop_corner_room,
    find_edges,
    rooms_bsp,
    rooms_corridor,
    rooms_open,
    spanning_doors,
    to_cells,
    uniform_int,
)

__all__ = ["SIZE_BANDS_M2", "Layout", "generate_layout"]

SIZE_BANDS_M2: dict[str, tuple[float, float]] = {
    "small": (0.0, 31.0),
    "medium": (36.0, 66.0),
    "large": (69.0, 1000.0),
}
"""Free-area bands (m²) of the size classes, from the DA-HGNN paper."""

# Practical limits applied on top of SIZE_BANDS_M2.
_MIN_FREE_AREA_M2 = 10.0
_MAX_FREE_AREA_M2 = 400.0
# Free-area targets actually drawn (a little inside the accepted bands).
_TARGET_M2: dict[str, tuple[float, float]] = {
    "small": (11.0, 30.0),
    "medium": (37.5, 64.5),
    "large": (72.0, 390.0),
}
# Generator styles and their probabilities per size class.
_STYLES: dict[str, tuple[tuple[str, float], ...]] = {
    "small": (("bsp", 0.6), ("open", 0.4)),
    "medium": (("bsp", 0.4), ("corridor", 0.3), ("open", 0.3)),
    "large": (("bsp", 0.35), ("corridor", 0.35), ("open", 0.3)),
}
_FILL_GUESS: dict[str, float] = {"bsp": 0.89, "corridor": 0.92, "open": 0.91}

_ROBOT_RADIUS_M = 0.18
_DOOR_MIN_M = 0.8
_DOOR_MAX_M = 1.2
_GRID_MARGIN_CELLS = 2
_MAX_ATTEMPTS = 10


@dataclass(frozen=True)
class Layout:
    """A generated floor layout on a regular grid.

    Attributes:
        free: ``(H, W)`` bool array, True = free floor.  Row = y (row 0 is
            the south edge), column = x.
        height_m: ``(H, W)`` float32 obstacle heights in metres: 0.0 on free
            cells, the wall height on walls, 0.4-1.0 on furniture.
        cell_m: metres per cell.
    """

    free: np.ndarray
    height_m: np.ndarray
    cell_m: float

    @property
    def free_area_m2(self) -> float:
        """Free floor area in square metres."""
        return float(np.count_nonzero(self.free)) * self.cell_m * self.cell_m


# ---------------------------------------------------------------------------
# One attempt and the public entry point
# ---------------------------------------------------------------------------


def _attempt(
    style: str,
    w_c: int,
    h_c: int,
    rng: np.random.Generator,
    cell_m: float,
    wall_height: float,
    furniture: bool,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Build one layout with an interior of ``w_c`` x ``h_c`` cells."""
    wall_t = int(rng.integers(1, 4))
    out_t = int(rng.integers(2, 4))
    pad = _GRID_MARGIN_CELLS + out_t
    p = LayoutParams(
        cell_m=cell_m,
        wall_t=wall_t,
        door_min=math.ceil(_DOOR_MIN_M / cell_m - 1e-9),
        door_max=math.floor(_DOOR_MAX_M / cell_m + 1e-9),
        door_margin=to_cells(0.1, cell_m),
        min_room=to_cells(2.2, cell_m),
        max_room=to_cells(7.0, cell_m),
        cspace_thr_cells=(_ROBOT_RADIUS_M + 0.5 * cell_m) / cell_m,
    )
    interior: Rect = (pad, pad, pad + w_c, pad + h_c)
    rooms = _plan_rooms(style, interior, rng, p)
    min_len = p.door_min + 2 * p.door_margin
    edges = find_edges(rooms, wall_t, min_len)
    doors = spanning_doors(rooms, edges, rng)
    if doors is None:
        return None

    free, door_rects = _carve(rooms, doors, (h_c + 2 * pad, w_c + 2 * pad), rng, p)
    if ndimage.label(free, structure=FOUR)[1] != 1:
        return None
    height = np.where(free, np.float32(0.0), np.float32(wall_height)).astype(np.float32)
    g = Grid(free, height, p)
    if ndimage.label(g.cspace, structure=EIGHT)[1] != 1:
        return None
    _keep_doors_clear(g, doors, door_rects, cell_m)

    for room in rooms:
        if room.kind == "open":
            add_partitions(g, room.rect, rng, wall_height)
    if furniture:
        for room in rooms:
            if room.kind != "corridor":
                add_furniture(g, room.rect, rng)
    return _connected(g, p, wall_height)


def _plan_rooms(style: str, interior: Rect, rng: np.random.Generator, p: LayoutParams) -> list[Room]:
    """The rooms of the interior in the given style (a corridor plan that does not fit: offices)."""
    rooms: list[Room] | None
    if style == "corridor":
        rooms = rooms_corridor(interior, rng, p)
        if rooms is None:
            rooms = rooms_bsp(interior, rng, p)
    elif style == "open":
        rooms = drop_corner_room(rooms_open(interior, rng, p), interior, p, rng)
    else:
        rooms = drop_corner_room(rooms_bsp(interior, rng, p), interior, p, rng)
    return rooms


def _carve(
    rooms: list[Room], doors: list[Edge], shape: tuple[int, int], rng: np.random.Generator, p: LayoutParams
) -> tuple[np.ndarray, list[Rect]]:
    """(free cells of the rooms and the doors, the door rectangles): each door of random width and
    place along its wall."""
    free = np.zeros(shape, dtype=bool)
    for room in rooms:
        x0, y0, x1, y1 = room.rect
        free[y0:y1, x0:x1] = True
    door_rects: list[Rect] = []
    for e in doors:
        span = e.ov_hi - e.ov_lo - 2 * p.door_margin
        dw = uniform_int(rng, p.door_min, min(p.door_max, span))
        d0 = uniform_int(rng, e.ov_lo + p.door_margin, e.ov_hi - p.door_margin - dw)
        if e.vertical:
            door_rects.append((e.wall_lo, d0, e.wall_hi, d0 + dw))
        else:
            door_rects.append((d0, e.wall_lo, d0 + dw, e.wall_hi))
        x0, y0, x1, y1 = door_rects[-1]
        free[y0:y1, x0:x1] = True
    return free, door_rects


def _keep_doors_clear(g: Grid, doors: list[Edge], door_rects: list[Rect], cell_m: float) -> None:
    """Mark the approach to each door (0.6 m across the wall, 0.15 m along it) where no obstacle may go."""
    keep_perp = to_cells(0.6, cell_m)
    keep_along = to_cells(0.15, cell_m)
    for e, (x0, y0, x1, y1) in zip(doors, door_rects, strict=True):
        if e.vertical:
            kx0, ky0, kx1, ky1 = (
                x0 - keep_perp,
                y0 - keep_along,
                x1 + keep_perp,
                y1 + keep_along,
            )
        else:
            kx0, ky0, kx1, ky1 = (
                x0 - keep_along,
                y0 - keep_perp,
                x1 + keep_along,
                y1 + keep_perp,
            )
        g.keepout[max(ky0, 0) : ky1, max(kx0, 0) : kx1] = True


def _connected(g: Grid, p: LayoutParams, wall_height: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Final safety net: drop any free pocket, then verify both connectivities; None if the
    configuration space is not one piece."""
    free, cspace = g.free, g.cspace
    labels, n = ndimage.label(free, structure=FOUR)
    if n != 1:
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        pocket = free & (labels != int(np.argmax(sizes)))
        free = free & ~pocket
        g.height[pocket] = np.float32(wall_height)
        cspace = cspace_of(free, p)
    if ndimage.label(cspace, structure=EIGHT)[1] != 1:
        return None
    return free, g.height


def _rect_dims(area_m2: float, aspect: float, cell_m: float) -> tuple[int, int]:
    w = max(1, round(math.sqrt(area_m2 * aspect) / cell_m))
    h = max(1, round(area_m2 / (w * cell_m * cell_m)))
    return w, h


def _fallback(
    target_m2: float, lo: float, hi: float, cell_m: float, wall_height: float
) -> tuple[np.ndarray, np.ndarray]:
    """Single rectangular room whose area is within [lo, hi] by construction."""
    w, h = _rect_dims(target_m2, 1.25, cell_m)
    while w * h * cell_m * cell_m > hi and h > 1:
        h -= 1
    while w * h * cell_m * cell_m < lo:
        h += 1
    pad = _GRID_MARGIN_CELLS + 2
    free = np.zeros((h + 2 * pad, w + 2 * pad), dtype=bool)
    free[pad : pad + h, pad : pad + w] = True
    height = np.where(free, np.float32(0.0), np.float32(wall_height)).astype(np.float32)
    return free, height


def generate_layout(
    size_class: str,
    rng: np.random.Generator,
    *,
    cell_m: float = 0.05,
    wall_height_m: float = 2.5,
    furniture: bool = True,
) -> Layout:
    """Generate a random indoor floor layout of the given size class.

    Args:
        size_class: ``"small"``, ``"medium"`` or ``"large"`` (see
            :data:`SIZE_BANDS_M2`).
        rng: the only source of randomness; the same state gives the same
            layout.
        cell_m: grid resolution, metres per cell (0 < cell_m <= 0.25).
        wall_height_m: height of walls in metres (> 0).
        furniture: whether to scatter furniture blocks in the rooms.

    Returns:
        A :class:`Layout` whose free area lies in the class band (small
        10-31 m², medium 36-66 m², large 69-400 m²).

    Raises:
        ValueError: unknown size class or invalid ``cell_m``/``wall_height_m``.
    """
    if size_class not in SIZE_BANDS_M2:
        raise ValueError(f"unknown size class {size_class!r}; expected one of {sorted(SIZE_BANDS_M2)}")
    if not 0.0 < cell_m <= 0.25:
        raise ValueError(f"cell_m must be in (0, 0.25], got {cell_m}")
    if not wall_height_m > 0.0:
        raise ValueError(f"wall_height_m must be > 0, got {wall_height_m}")
    band_lo, band_hi = SIZE_BANDS_M2[size_class]
    lo = max(band_lo, _MIN_FREE_AREA_M2)
    hi = min(band_hi, _MAX_FREE_AREA_M2)

    target = float(rng.uniform(*_TARGET_M2[size_class]))
    styles = _STYLES[size_class]
    u = float(rng.random())
    style = styles[-1][0]
    acc = 0.0
    for name, prob in styles:
        acc += prob
        if u < acc:
            style = name
            break
    fill = _FILL_GUESS[style]
    for attempt in range(_MAX_ATTEMPTS):
        if attempt >= _MAX_ATTEMPTS // 2:
            style = "bsp"
        if style == "corridor":
            aspect = float(rng.uniform(1.5, 3.5))
        else:
            aspect = float(rng.uniform(1.0, 2.0))
        w_c, h_c = _rect_dims(target / fill, aspect, cell_m)
        if rng.random() < 0.5:
            w_c, h_c = h_c, w_c
        result = _attempt(style, w_c, h_c, rng, cell_m, wall_height_m, furniture)
        if result is None:
            continue
        free, height = result
        area = float(np.count_nonzero(free)) * cell_m * cell_m
        if lo <= area <= hi:
            return Layout(free=free, height_m=height, cell_m=cell_m)
        rect_area = w_c * h_c * cell_m * cell_m
        fill = min(max(area / rect_area, 0.5), 1.0)
    free, height = _fallback(target, lo, hi, cell_m, wall_height_m)
    return Layout(free=free, height_m=height, cell_m=cell_m)


# ---------------------------------------------------------------------------------- test geometry


class TwoRooms(NamedTuple):
    """A :func:`two_rooms` layout."""

    free: np.ndarray
    """(H, W) bool free space, ``[iy, ix]``."""
    far: np.ndarray
    """(H, W) bool: the cells on the east side of the wall's centre line (the far room)."""
    cell_m: float


def two_rooms(
    doorway_m: float,
    *,
    wall_angle_deg: float = 0.0,
    wall_m: float = 0.05,
    jagged: bool = False,
    room_m: tuple[float, float] = (3.0, 3.0),
    cell_m: float = 0.05,
    seed: int = 0,
) -> TwoRooms:
    """Free space (H, W) bool, ``[iy, ix]`` as everywhere: two rooms side by side (west and east,
    each ``room_m`` = (width, depth) metres) joined by one doorway in the wall between them. For a
    geometric suite of doorway tests (which doorways a robot of a given footprint passes).

    The wall's centre line passes through the map's centre, turned ``wall_angle_deg`` from the
    north-south axis (0: straight; up to 60 keeps it a wall between the rooms); its thickness is
    ``wall_m`` (rasterised: a cell is wall when its centre lies within half the thickness of the
    centre line, or within half the cell's extent across a slanted line, so that a one-cell wall
    stays closed). The doorway is the part of the wall within ``doorway_m / 2`` of the centre,
    measured along the wall: for a straight wall, exactly ``doorway_m`` of clear width between the
    obstacle cells when that is a whole number of cells. ``jagged``: both faces of the wall
    and the doorway's two ends get one-cell notches and bumps at random (from ``seed``), like a
    rasterised real wall. The outer walls are two cells thick.
    """
    if not 0.0 <= abs(wall_angle_deg) <= 60.0:
        raise ValueError(f"wall_angle_deg must be within [-60, 60], got {wall_angle_deg}")
    if doorway_m <= 0 or wall_m <= 0 or cell_m <= 0:
        raise ValueError("doorway_m, wall_m and cell_m must be positive")
    border = 2
    width = 2 * round(room_m[0] / cell_m) + border * 2 + 1
    height = round(room_m[1] / cell_m) + border * 2
    free = np.zeros((height, width), dtype=bool)
    free[border:-border, border:-border] = True
    iy, ix = np.mgrid[0:height, 0:width]
    cells = round(doorway_m / cell_m)
    cx = (width // 2 + 0.5) * cell_m  # the centre line through a cell centre; the doorway centred on
    cy = (height // 2 + (0.5 if cells % 2 else 0.0)) * cell_m  # a cell (odd width) or an edge (even)
    x, y = (ix + 0.5) * cell_m - cx, (iy + 0.5) * cell_m - cy
    a = math.radians(wall_angle_deg)
    normal = (math.cos(a), -math.sin(a))  # across the wall (x-ward at 0°)
    across = x * normal[0] + y * normal[1]
    along = x * math.sin(a) + y * math.cos(a)
    half = max(wall_m, cell_m * (abs(math.cos(a)) + abs(math.sin(a)))) / 2
    wall = (np.abs(across) <= half + 1e-9) & (np.abs(along) >= doorway_m / 2)
    if jagged:
        rng = np.random.default_rng(seed)
        edge = ndimage.binary_dilation(wall) & ~wall
        bumps = edge & (rng.random(wall.shape) < 0.3)
        notches = wall & ~ndimage.binary_erosion(wall) & (rng.random(wall.shape) < 0.3)
        inner = np.abs(across) <= half - cell_m + 1e-9  # keep the wall closed: never notch its core
        wall = (wall | bumps) & ~(notches & ~inner)
    free &= ~wall
    return TwoRooms(free, across > 0, cell_m)
