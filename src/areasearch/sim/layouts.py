"""Seeded procedural generator of indoor floor layouts (pipeline stage "scene").

This module provides procedural layouts for training variety: each call to
:func:`generate_layout` draws a new floor plan (offices from a recursive binary
space partition, a corridor with rooms on both sides, or an open plan with
partition walls), connects the rooms with doors and scatters a few furniture
blocks inside them.  Rooms have sides of roughly 2.2-7 m (open-plan zones up to
14 m), walls are 1-3 cells thick, doors 0.8-1.2 m wide and furniture blocks
0.4-1.5 m per side and 0.4-1.0 m high (tall enough for the camera to see from any robot pose).

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
_FURN_SIDE_M = (0.4, 1.5)
_FURN_HEIGHT_M = (0.4, 1.0)
_GRID_MARGIN_CELLS = 2
_MAX_ATTEMPTS = 10

_FOUR = ndimage.generate_binary_structure(2, 1)
_EIGHT = ndimage.generate_binary_structure(2, 2)

# (x0, y0, x1, y1) in cells, half-open: columns x0..x1-1, rows y0..y1-1.
_Rect = tuple[int, int, int, int]


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


@dataclass(frozen=True)
class _Room:
    rect: _Rect
    kind: str  # "room", "corridor" or "open"


@dataclass(frozen=True)
class _Edge:
    """Two rooms facing each other across a straight wall."""

    a: int
    b: int
    vertical: bool  # True: wall runs along y (rooms side by side in x)
    wall_lo: int  # first wall cell across the wall
    wall_hi: int  # one past the last wall cell across the wall
    ov_lo: int  # start of the shared extent along the wall
    ov_hi: int  # end (exclusive) of the shared extent along the wall


@dataclass(frozen=True)
class _Params:
    """Metric parameters converted to cells."""

    cell_m: float
    wall_t: int
    door_min: int
    door_max: int
    door_margin: int
    min_room: int
    max_room: int
    cspace_thr_cells: float


def _cells(length_m: float, cell_m: float) -> int:
    return max(1, round(length_m / cell_m))


def _uniform_int(rng: np.random.Generator, lo: int, hi: int) -> int:
    """Uniform integer in [lo, hi] (inclusive); lo if the range is empty."""
    if hi <= lo:
        return lo
    return int(rng.integers(lo, hi + 1))


# ---------------------------------------------------------------------------
# Room generators: each returns rooms as disjoint rectangles separated by
# walls exactly ``wall_t`` cells thick.
# ---------------------------------------------------------------------------


def _bsp(
    rect: _Rect,
    rng: np.random.Generator,
    min_c: int,
    max_c: int,
    t: int,
    p_stop: float,
) -> list[_Rect]:
    """Recursive binary space partition of ``rect`` into rooms."""
    out: list[_Rect] = []
    stack = [rect]
    while stack:
        x0, y0, x1, y1 = stack.pop()
        w, h = x1 - x0, y1 - y0
        can_x = w >= 2 * min_c + t
        can_y = h >= 2 * min_c + t
        must = w > max_c or h > max_c
        if not (can_x or can_y) or (not must and rng.random() < p_stop):
            out.append((x0, y0, x1, y1))
            continue
        if can_x and can_y:
            if w >= 1.3 * h:
                split_x = True
            elif h >= 1.3 * w:
                split_x = False
            else:
                split_x = bool(rng.random() < 0.5)
        else:
            split_x = can_x
        if split_x:
            s = _uniform_int(rng, x0 + min_c, x1 - min_c - t)
            stack.append((s + t, y0, x1, y1))
            stack.append((x0, y0, s, y1))
        else:
            s = _uniform_int(rng, y0 + min_c, y1 - min_c - t)
            stack.append((x0, s + t, x1, y1))
            stack.append((x0, y0, x1, s))
    return out


def _rooms_bsp(rect: _Rect, rng: np.random.Generator, p: _Params) -> list[_Room]:
    rects = _bsp(rect, rng, p.min_room, p.max_room, p.wall_t, 0.3)
    return [_Room(r, "room") for r in rects]


def _rooms_open(rect: _Rect, rng: np.random.Generator, p: _Params) -> list[_Room]:
    min_c = _cells(3.0, p.cell_m)
    max_c = _cells(14.0, p.cell_m)
    big = _cells(4.5, p.cell_m)
    rects = _bsp(rect, rng, min_c, max_c, p.wall_t, 0.5)
    rooms: list[_Room] = []
    for r in rects:
        w, h = r[2] - r[0], r[3] - r[1]
        rooms.append(_Room(r, "open" if min(w, h) >= big else "room"))
    return rooms


def _split_row(x0: int, x1: int, rng: np.random.Generator, t: int, lo: int, hi: int) -> list[tuple[int, int]]:
    """Split the interval [x0, x1) into segments of length ~[lo, hi] with gaps t."""
    segs: list[tuple[int, int]] = []
    start = x0
    while True:
        rest = x1 - start
        if rest <= hi or rest < 2 * lo + t:
            segs.append((start, x1))
            return segs
        length = _uniform_int(rng, lo, min(hi, rest - lo - t))
        segs.append((start, start + length))
        start += length + t


def _rooms_corridor(rect: _Rect, rng: np.random.Generator, p: _Params) -> list[_Room] | None:
    """A corridor along the long axis with rooms on one or both sides."""
    t = p.wall_t
    x0, y0, x1, y1 = rect
    transposed = (y1 - y0) > (x1 - x0)
    if transposed:  # work with a horizontal corridor, transpose at the end
        x0, y0, x1, y1 = y0, x0, y1, x1
    min_c = p.min_room
    cw = _cells(float(rng.uniform(1.2, 2.0)), p.cell_m)
    depth = y1 - y0
    rooms: list[_Room] = []
    # Optional room block closing one end of the corridor.
    if x1 - x0 >= 4 * min_c and rng.random() < 0.5:
        end_len = _uniform_int(rng, min_c, min(_cells(5.0, p.cell_m), (x1 - x0) // 3))
        if rng.random() < 0.5:
            end: _Rect = (x1 - end_len, y0, x1, y1)
            x1 = x1 - end_len - t
        else:
            end = (x0, y0, x0 + end_len, y1)
            x0 = x0 + end_len + t
        rooms += [_Room(r, "room") for r in _bsp(end, rng, min_c, p.max_room, t, 0.5)]
    if depth >= 2 * min_c + cw + 2 * t:
        d_south = _uniform_int(rng, min_c, depth - cw - 2 * t - min_c)
        strips = [(y0, y0 + d_south), (y0 + d_south + cw + 2 * t, y1)]
        cy0 = y0 + d_south + t
    elif depth >= min_c + cw + t:
        cw = min(depth - min_c - t, _cells(2.0, p.cell_m))
        if rng.random() < 0.5:
            strips = [(y0 + cw + t, y1)]
            cy0 = y0
        else:
            strips = [(y0, y1 - cw - t)]
            cy0 = y1 - cw
    else:
        return None
    rooms.append(_Room((x0, cy0, x1, cy0 + cw), "corridor"))
    seg_lo = _cells(2.5, p.cell_m)
    seg_hi = _cells(5.0, p.cell_m)
    for sy0, sy1 in strips:
        for sx0, sx1 in _split_row(x0, x1, rng, t, seg_lo, seg_hi):
            seg = (sx0, sy0, sx1, sy1)
            rooms += [_Room(r, "room") for r in _bsp(seg, rng, min_c, p.max_room, t, 0.7)]
    if transposed:
        rooms = [_Room((r.rect[1], r.rect[0], r.rect[3], r.rect[2]), r.kind) for r in rooms]
    return rooms


# ---------------------------------------------------------------------------
# Room graph and doors
# ---------------------------------------------------------------------------


def _find_edges(rooms: list[_Room], t: int, min_len: int) -> list[_Edge]:
    edges: list[_Edge] = []
    n = len(rooms)
    for i in range(n):
        a = rooms[i].rect
        for j in range(i + 1, n):
            b = rooms[j].rect
            for p, q, pi, qi in ((a, b, i, j), (b, a, j, i)):
                if q[0] - p[2] == t:  # p west of q
                    lo, hi = max(p[1], q[1]), min(p[3], q[3])
                    if hi - lo >= min_len:
                        edges.append(_Edge(pi, qi, True, p[2], q[0], lo, hi))
                if q[1] - p[3] == t:  # p south of q
                    lo, hi = max(p[0], q[0]), min(p[2], q[2])
                    if hi - lo >= min_len:
                        edges.append(_Edge(pi, qi, False, p[3], q[1], lo, hi))
    return edges


def _find(parent: list[int], i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


def _spanning_doors(rooms: list[_Room], edges: list[_Edge], rng: np.random.Generator) -> list[_Edge] | None:
    """Random spanning tree of doors (corridor doors first) plus a few loops."""
    keys = rng.random(len(edges))
    order = sorted(
        range(len(edges)),
        key=lambda k: (
            0 if "corridor" in (rooms[edges[k].a].kind, rooms[edges[k].b].kind) else 1,
            float(keys[k]),
        ),
    )
    parent = list(range(len(rooms)))
    chosen: list[_Edge] = []
    rest: list[_Edge] = []
    for k in order:
        e = edges[k]
        ra, rb = _find(parent, e.a), _find(parent, e.b)
        if ra != rb:
            parent[ra] = rb
            chosen.append(e)
        else:
            rest.append(e)
    if len(chosen) != len(rooms) - 1:
        return None
    extra = rng.random(len(rest))
    chosen += [e for e, u in zip(rest, extra, strict=True) if u < 0.15]
    return chosen


def _is_connected(n: int, edges: list[_Edge]) -> bool:
    parent = list(range(n))
    for e in edges:
        parent[_find(parent, e.a)] = _find(parent, e.b)
    return len({_find(parent, i) for i in range(n)}) == 1


def _drop_corner_room(rooms: list[_Room], interior: _Rect, p: _Params, rng: np.random.Generator) -> list[_Room]:
    """Sometimes remove a corner room to get an L-shaped or notched footprint."""
    if len(rooms) < 4 or rng.random() >= 0.35:
        return rooms
    x0, y0, x1, y1 = interior
    total = (x1 - x0) * (y1 - y0)
    corners = [
        i
        for i, r in enumerate(rooms)
        if r.kind != "corridor"
        and (r.rect[0] == x0 or r.rect[2] == x1)
        and (r.rect[1] == y0 or r.rect[3] == y1)
        and (r.rect[2] - r.rect[0]) * (r.rect[3] - r.rect[1]) <= 0.25 * total
    ]
    if not corners:
        return rooms
    k = corners[int(rng.integers(len(corners)))]
    kept = rooms[:k] + rooms[k + 1 :]
    min_len = p.door_min + 2 * p.door_margin
    if _is_connected(len(kept), _find_edges(kept, p.wall_t, min_len)):
        return kept
    return rooms


# ---------------------------------------------------------------------------
# Obstacle placement with connectivity checks
# ---------------------------------------------------------------------------


class _Grid:
    """Mutable working state of one layout attempt."""

    def __init__(self, free: np.ndarray, height: np.ndarray, p: _Params) -> None:
        self.free = free
        self.height = height
        self.p = p
        self.keepout = np.zeros_like(free)
        self.cspace = _cspace(free, p)

    def try_place(self, rect: _Rect, height: float, room: _Rect, keep: float) -> bool:
        """Place an obstacle if free space and C-space stay connected.

        Connectivity is first checked locally: if the free cells on the ring
        around the block (resp. the C-space cells on the band just outside
        the region the block removes from the C-space) form one connected
        piece, every path through the block can be rerouted around it.  Only
        when that local test is inconclusive is the whole grid labelled.
        """
        x0, y0, x1, y1 = rect
        free, cs = self.free, self.cspace
        gh, gw = free.shape
        if x0 < 1 or y0 < 1 or x1 > gw - 1 or y1 > gh - 1:
            return False
        if not free[y0:y1, x0:x1].all() or self.keepout[y0:y1, x0:x1].any():
            return False
        # C-space update: cells within the robot clearance of the new block.
        r = self.p.cspace_thr_cells
        k = math.ceil(r) + 2
        wx0, wy0 = max(x0 - k, 0), max(y0 - k, 0)
        wx1, wy1 = min(x1 + k, gw), min(y1 + k, gh)
        xs = np.arange(wx0, wx1)[None, :]
        ys = np.arange(wy0, wy1)[:, None]
        dx = np.maximum(np.maximum(x0 - xs, xs - (x1 - 1)), 0)
        dy = np.maximum(np.maximum(y0 - ys, ys - (y1 - 1)), 0)
        dist = np.sqrt((dx * dx + dy * dy).astype(np.float64))
        near = dist <= r
        cs_win = cs[wy0:wy1, wx0:wx1] & ~near
        rx0, ry0, rx1, ry1 = room
        removed = cs[wy0:wy1, wx0:wx1] & near
        sub = removed[max(ry0 - wy0, 0) : max(ry1 - wy0, 0), max(rx0 - wx0, 0) : max(rx1 - wx0, 0)]
        before = int(np.count_nonzero(cs[ry0:ry1, rx0:rx1]))
        if before - int(np.count_nonzero(sub)) < keep * before:
            return False
        band = cs_win & (dist <= r + 1.5)
        if ndimage.label(band, structure=_EIGHT)[1] > 1:
            full = cs.copy()
            full[wy0:wy1, wx0:wx1] = cs_win
            if ndimage.label(full, structure=_EIGHT)[1] != 1:
                return False
        # Free space: ring of cells around the block (4-connectivity).
        ring = free[y0 - 1 : y1 + 1, x0 - 1 : x1 + 1].copy()
        ring[1:-1, 1:-1] = False
        if ndimage.label(ring, structure=_FOUR)[1] > 1:
            full = free.copy()
            full[y0:y1, x0:x1] = False
            if ndimage.label(full, structure=_FOUR)[1] != 1:
                return False
        free[y0:y1, x0:x1] = False
        cs[wy0:wy1, wx0:wx1] = cs_win
        self.height[y0:y1, x0:x1] = np.float32(height)
        return True


def _cspace(free: np.ndarray, p: _Params) -> np.ndarray:
    dist = ndimage.distance_transform_edt(free)
    return np.asarray(dist > p.cspace_thr_cells)


def _add_partitions(g: _Grid, room: _Rect, rng: np.random.Generator, wall_height: float) -> None:
    """Stub partition walls attached to one side of an open-plan zone."""
    p = g.p
    x0, y0, x1, y1 = room
    w, h = x1 - x0, y1 - y0
    vertical = bool(rng.random() < (0.75 if w >= h else 0.25))
    if not vertical:  # work in (along, across) = (y, x)
        x0, y0, x1, y1 = y0, x0, y1, x1
        w, h = h, w
    spacing = _cells(2.0, p.cell_m)
    gap = _cells(1.2, p.cell_m)
    t = p.wall_t
    placed: list[int] = []
    for _ in range(int(rng.integers(1, 4))):
        lo, hi = x0 + spacing, x1 - spacing - t
        if hi < lo:
            return
        pos = _uniform_int(rng, lo, hi)
        length = min(round(float(rng.uniform(0.35, 0.65)) * h), h - gap)
        from_start = bool(rng.random() < 0.5)
        if any(abs(pos - q) < spacing for q in placed) or length < gap:
            continue
        a0 = y0 if from_start else y1 - length
        rect: _Rect = (pos, a0, pos + t, a0 + length)
        if not vertical:
            rect = (rect[1], rect[0], rect[3], rect[2])
        if g.try_place(rect, wall_height, room, 0.5):
            placed.append(pos)


def _add_furniture(g: _Grid, room: _Rect, rng: np.random.Generator) -> None:
    p = g.p
    x0, y0, x1, y1 = room
    w, h = x1 - x0, y1 - y0
    area_m2 = w * h * p.cell_m**2
    n_max = min(4, int(area_m2 / 6.0))
    n = _uniform_int(rng, n_max // 2, n_max)
    side_lo = _cells(_FURN_SIDE_M[0], p.cell_m)
    side_hi = math.floor(_FURN_SIDE_M[1] / p.cell_m + 1e-9)
    clear = _cells(0.5, p.cell_m)
    for _ in range(n):
        for _try in range(4):
            bw = _uniform_int(rng, side_lo, side_hi)
            bh = _uniform_int(rng, side_lo, side_hi)
            height = float(rng.uniform(*_FURN_HEIGHT_M))
            mode = float(rng.random())
            if bw > w - 2 * clear or bh > h - 2 * clear:
                continue
            if mode < 0.55:  # against one wall
                side = int(rng.integers(4))
                bx = _uniform_int(rng, x0, x1 - bw)
                by = _uniform_int(rng, y0, y1 - bh)
                if side == 0:
                    by = y0
                elif side == 1:
                    by = y1 - bh
                elif side == 2:
                    bx = x0
                else:
                    bx = x1 - bw
            elif mode < 0.75:  # in a corner
                bx = x0 if rng.random() < 0.5 else x1 - bw
                by = y0 if rng.random() < 0.5 else y1 - bh
            else:  # free-standing, away from the walls
                bx = _uniform_int(rng, x0 + clear, x1 - bw - clear)
                by = _uniform_int(rng, y0 + clear, y1 - bh - clear)
            height = min(max(height, _FURN_HEIGHT_M[0]), _FURN_HEIGHT_M[1])
            if g.try_place((bx, by, bx + bw, by + bh), height, room, 0.4):
                break


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
    p = _Params(
        cell_m=cell_m,
        wall_t=wall_t,
        door_min=math.ceil(_DOOR_MIN_M / cell_m - 1e-9),
        door_max=math.floor(_DOOR_MAX_M / cell_m + 1e-9),
        door_margin=_cells(0.1, cell_m),
        min_room=_cells(2.2, cell_m),
        max_room=_cells(7.0, cell_m),
        cspace_thr_cells=(_ROBOT_RADIUS_M + 0.5 * cell_m) / cell_m,
    )
    interior: _Rect = (pad, pad, pad + w_c, pad + h_c)
    rooms: list[_Room] | None
    if style == "corridor":
        rooms = _rooms_corridor(interior, rng, p)
        if rooms is None:
            rooms = _rooms_bsp(interior, rng, p)
    elif style == "open":
        rooms = _drop_corner_room(_rooms_open(interior, rng, p), interior, p, rng)
    else:
        rooms = _drop_corner_room(_rooms_bsp(interior, rng, p), interior, p, rng)

    min_len = p.door_min + 2 * p.door_margin
    edges = _find_edges(rooms, wall_t, min_len)
    doors = _spanning_doors(rooms, edges, rng)
    if doors is None:
        return None

    shape = (h_c + 2 * pad, w_c + 2 * pad)
    free = np.zeros(shape, dtype=bool)
    for room in rooms:
        x0, y0, x1, y1 = room.rect
        free[y0:y1, x0:x1] = True
    keep_perp = _cells(0.6, cell_m)
    keep_along = _cells(0.15, cell_m)
    door_rects: list[_Rect] = []
    for e in doors:
        span = e.ov_hi - e.ov_lo - 2 * p.door_margin
        dw = _uniform_int(rng, p.door_min, min(p.door_max, span))
        d0 = _uniform_int(rng, e.ov_lo + p.door_margin, e.ov_hi - p.door_margin - dw)
        if e.vertical:
            door_rects.append((e.wall_lo, d0, e.wall_hi, d0 + dw))
        else:
            door_rects.append((d0, e.wall_lo, d0 + dw, e.wall_hi))
        x0, y0, x1, y1 = door_rects[-1]
        free[y0:y1, x0:x1] = True

    if ndimage.label(free, structure=_FOUR)[1] != 1:
        return None
    height = np.where(free, np.float32(0.0), np.float32(wall_height)).astype(np.float32)
    g = _Grid(free, height, p)
    if ndimage.label(g.cspace, structure=_EIGHT)[1] != 1:
        return None
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

    for room in rooms:
        if room.kind == "open":
            _add_partitions(g, room.rect, rng, wall_height)
    if furniture:
        for room in rooms:
            if room.kind != "corridor":
                _add_furniture(g, room.rect, rng)

    # Final safety net: drop any free pocket, then verify both connectivities.
    free, cspace = g.free, g.cspace
    labels, n = ndimage.label(free, structure=_FOUR)
    if n != 1:
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        pocket = free & (labels != int(np.argmax(sizes)))
        free = free & ~pocket
        g.height[pocket] = np.float32(wall_height)
        cspace = _cspace(free, p)
    if ndimage.label(cspace, structure=_EIGHT)[1] != 1:
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
