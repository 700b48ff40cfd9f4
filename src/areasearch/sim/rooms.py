"""Room plans of the procedural layouts: rooms as disjoint rectangles and the doors between them.

:func:`rooms_bsp` (offices from a recursive binary space partition), :func:`rooms_corridor` (a
corridor with rooms on one or both sides) and :func:`rooms_open` (open-plan zones) cut the interior
of a layout into rooms separated by walls exactly ``wall_t`` cells thick; :func:`drop_corner_room`
sometimes removes a corner room (an L-shaped or notched footprint). :func:`find_edges` finds the
walls two rooms share and :func:`spanning_doors` picks the doors: a random spanning tree, corridor
doors first, plus a few loops. Used by :func:`areasearch.sim.layouts.generate_layout`; all the
randomness comes from the ``rng`` argument, drawn in a fixed order.

Units: cells; rectangles (x0, y0, x1, y1) half-open.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

Rect = tuple[int, int, int, int]
"""(x0, y0, x1, y1) in cells, half-open: columns x0..x1-1, rows y0..y1-1."""


@dataclass(frozen=True)
class Room:
    """One room of a plan."""

    rect: Rect
    kind: str  # "room", "corridor" or "open"


@dataclass(frozen=True)
class Edge:
    """Two rooms facing each other across a straight wall."""

    a: int
    b: int
    vertical: bool  # True: wall runs along y (rooms side by side in x)
    wall_lo: int  # first wall cell across the wall
    wall_hi: int  # one past the last wall cell across the wall
    ov_lo: int  # start of the shared extent along the wall
    ov_hi: int  # end (exclusive) of the shared extent along the wall


@dataclass(frozen=True)
class LayoutParams:
    """Metric parameters converted to cells."""

    cell_m: float
    wall_t: int
    door_min: int
    door_max: int
    door_margin: int
    min_room: int
    max_room: int
    cspace_thr_cells: float


def to_cells(length_m: float, cell_m: float) -> int:
    """``length_m`` in whole cells, at least one."""
    return max(1, round(length_m / cell_m))


def uniform_int(rng: np.random.Generator, lo: int, hi: int) -> int:
    """Uniform integer in [lo, hi] (inclusive); lo if the range is empty."""
    if hi <= lo:
        return lo
    return int(rng.integers(lo, hi + 1))


def _bsp(
    rect: Rect,
    rng: np.random.Generator,
    min_c: int,
    max_c: int,
    t: int,
    p_stop: float,
) -> list[Rect]:
    """Recursive binary space partition of ``rect`` into rooms."""
    out: list[Rect] = []
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
            s = uniform_int(rng, x0 + min_c, x1 - min_c - t)
            stack.append((s + t, y0, x1, y1))
            stack.append((x0, y0, s, y1))
        else:
            s = uniform_int(rng, y0 + min_c, y1 - min_c - t)
            stack.append((x0, s + t, x1, y1))
            stack.append((x0, y0, x1, s))
    return out


def rooms_bsp(rect: Rect, rng: np.random.Generator, p: LayoutParams) -> list[Room]:
    rects = _bsp(rect, rng, p.min_room, p.max_room, p.wall_t, 0.3)
    return [Room(r, "room") for r in rects]


def rooms_open(rect: Rect, rng: np.random.Generator, p: LayoutParams) -> list[Room]:
    min_c = to_cells(3.0, p.cell_m)
    max_c = to_cells(14.0, p.cell_m)
    big = to_cells(4.5, p.cell_m)
    rects = _bsp(rect, rng, min_c, max_c, p.wall_t, 0.5)
    rooms: list[Room] = []
    for r in rects:
        w, h = r[2] - r[0], r[3] - r[1]
        rooms.append(Room(r, "open" if min(w, h) >= big else "room"))
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
        length = uniform_int(rng, lo, min(hi, rest - lo - t))
        segs.append((start, start + length))
        start += length + t


def rooms_corridor(rect: Rect, rng: np.random.Generator, p: LayoutParams) -> list[Room] | None:
    """A corridor along the long axis with rooms on one or both sides."""
    t = p.wall_t
    x0, y0, x1, y1 = rect
    transposed = (y1 - y0) > (x1 - x0)
    if transposed:  # work with a horizontal corridor, transpose at the end
        x0, y0, x1, y1 = y0, x0, y1, x1
    min_c = p.min_room
    cw = to_cells(float(rng.uniform(1.2, 2.0)), p.cell_m)
    depth = y1 - y0
    rooms: list[Room] = []
    # Optional room block closing one end of the corridor.
    if x1 - x0 >= 4 * min_c and rng.random() < 0.5:
        end_len = uniform_int(rng, min_c, min(to_cells(5.0, p.cell_m), (x1 - x0) // 3))
        if rng.random() < 0.5:
            end: Rect = (x1 - end_len, y0, x1, y1)
            x1 = x1 - end_len - t
        else:
            end = (x0, y0, x0 + end_len, y1)
            x0 = x0 + end_len + t
        rooms += [Room(r, "room") for r in _bsp(end, rng, min_c, p.max_room, t, 0.5)]
    if depth >= 2 * min_c + cw + 2 * t:
        d_south = uniform_int(rng, min_c, depth - cw - 2 * t - min_c)
        strips = [(y0, y0 + d_south), (y0 + d_south + cw + 2 * t, y1)]
        cy0 = y0 + d_south + t
    elif depth >= min_c + cw + t:
        cw = min(depth - min_c - t, to_cells(2.0, p.cell_m))
        if rng.random() < 0.5:
            strips = [(y0 + cw + t, y1)]
            cy0 = y0
        else:
            strips = [(y0, y1 - cw - t)]
            cy0 = y1 - cw
    else:
        return None
    rooms.append(Room((x0, cy0, x1, cy0 + cw), "corridor"))
    seg_lo = to_cells(2.5, p.cell_m)
    seg_hi = to_cells(5.0, p.cell_m)
    for sy0, sy1 in strips:
        for sx0, sx1 in _split_row(x0, x1, rng, t, seg_lo, seg_hi):
            seg = (sx0, sy0, sx1, sy1)
            rooms += [Room(r, "room") for r in _bsp(seg, rng, min_c, p.max_room, t, 0.7)]
    if transposed:
        rooms = [Room((r.rect[1], r.rect[0], r.rect[3], r.rect[2]), r.kind) for r in rooms]
    return rooms


def find_edges(rooms: list[Room], t: int, min_len: int) -> list[Edge]:
    edges: list[Edge] = []
    n = len(rooms)
    for i in range(n):
        a = rooms[i].rect
        for j in range(i + 1, n):
            b = rooms[j].rect
            for p, q, pi, qi in ((a, b, i, j), (b, a, j, i)):
                if q[0] - p[2] == t:  # p west of q
                    lo, hi = max(p[1], q[1]), min(p[3], q[3])
                    if hi - lo >= min_len:
                        edges.append(Edge(pi, qi, True, p[2], q[0], lo, hi))
                if q[1] - p[3] == t:  # p south of q
                    lo, hi = max(p[0], q[0]), min(p[2], q[2])
                    if hi - lo >= min_len:
                        edges.append(Edge(pi, qi, False, p[3], q[1], lo, hi))
    return edges


def _find(parent: list[int], i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


def spanning_doors(rooms: list[Room], edges: list[Edge], rng: np.random.Generator) -> list[Edge] | None:
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
    chosen: list[Edge] = []
    rest: list[Edge] = []
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


def _is_connected(n: int, edges: list[Edge]) -> bool:
    parent = list(range(n))
    for e in edges:
        parent[_find(parent, e.a)] = _find(parent, e.b)
    return len({_find(parent, i) for i in range(n)}) == 1


def drop_corner_room(rooms: list[Room], interior: Rect, p: LayoutParams, rng: np.random.Generator) -> list[Room]:
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
    if _is_connected(len(kept), find_edges(kept, p.wall_t, min_len)):
        return kept
    return rooms
