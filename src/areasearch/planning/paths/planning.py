"""Planning a path: the FMM shortest path over a planning grid and the reading of a path off a
distance field.

:func:`plan_path` (:func:`plan_kernel` in the re-plans) marches from the goal and stops once the
robot's cell is settled, after a connectivity check that costs a fraction of an FMM
(:func:`connected`); :func:`descend` reads a path off a distance field by steepest descent, and
:func:`route_path` a robot's path off its decision-time field (:class:`~areasearch.planning.candidates.Routes`);
:func:`enclosed` tells whether a robot is walled in; :func:`block_robots` blocks the team-mates'
footprints on a grid for a detour round them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba
import numpy as np

from ..fmm import FMM_PAD, fmm_kernel

if TYPE_CHECKING:
    from ..candidates import Routes


@numba.njit(cache=True, nogil=True)
def descend(field: np.ndarray, start_y: int, start_x: int, max_len: int) -> np.ndarray:
    """Steepest descent on a distance field from ``start`` to its zero; (N, 2) cells, empty if the
    start is unreachable (inf) or the descent gets stuck."""
    h, w = field.shape
    out = np.empty((max_len, 2), dtype=np.int64)
    if not field[start_y, start_x] < np.inf:
        return out[:0]
    y, x = start_y, start_x
    n = 0
    out[0, 0] = y
    out[0, 1] = x
    n = 1
    while field[y, x] > 0.0 and n < max_len:
        best = field[y, x]
        by, bx = -1, -1
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dy == 0 and dx == 0:
                    continue
                ny, nx = y + dy, x + dx
                if 0 <= ny < h and 0 <= nx < w:
                    value = field[ny, nx]
                    if dy != 0 and dx != 0:
                        # no corner cutting between two blocked cells
                        if not (field[y, nx] < np.inf and field[ny, x] < np.inf):
                            continue
                    if value < best:
                        best, by, bx = value, ny, nx
        if by < 0:
            return out[:0]
        y, x = by, bx
        out[n, 0] = y
        out[n, 1] = x
        n += 1
    if field[y, x] > 0.0:
        return out[:0]
    return out[:n].copy()


@numba.njit(cache=True, nogil=True)
def enclosed(passable: np.ndarray, sy: int, sx: int, side: np.ndarray) -> bool:
    """True if the 4-connected component of (sy, sx) over ``passable`` (h, w), the start counting
    as passable, does not touch the edge of the window (``side`` (h * w) then holds 1 on it): a
    robot walled in there (by obstacles and bump marks) can reach nothing outside it."""
    h, w = passable.shape
    side[:] = 0
    queue = np.empty(h * w, dtype=np.int64)
    queue[0] = sy * w + sx
    side[queue[0]] = 1
    head, tail = 0, 1
    while head < tail:
        i = queue[head]
        head += 1
        y, x = i // w, i % w
        if y == 0 or x == 0 or y == h - 1 or x == w - 1:
            return False
        for j in (i + 1, i - 1, i + w, i - w):
            if side[j] == 0 and passable[j // w, j % w]:
                side[j] = 1
                queue[tail] = j
                tail += 1
    return True


CONNECTED, START_CLOSED, GOAL_CLOSED, NOT_HERE = 1, 2, 3, -1
"""Verdicts of :func:`connected`."""


@numba.njit(cache=True, nogil=True)
def connected(passable: np.ndarray, sy: int, sx: int, gy: int, gx: int, side: np.ndarray) -> int:
    """Whether (sy, sx) and (gy, gx) are 4-connected over ``passable`` (h, w), both ends counting
    as passable: ``CONNECTED``; ``START_CLOSED`` / ``GOAL_CLOSED`` when not, the start's / the
    goal's component not touching the edge of the window (so no larger window connects them);
    ``NOT_HERE`` when not within the window. ``side`` (h * w) uint8 receives 1 on the cells
    reached from the start (its whole component when ``START_CLOSED``), 2 from the goal.

    Breadth-first from both ends in turn, so a disconnection costs about twice the smaller
    component and a connection about the two half-way discs, a fraction of an FMM."""
    h, w = passable.shape
    side[:] = 0
    start, goal = sy * w + sx, gy * w + gx
    side[start] = 1
    if start == goal:
        return CONNECTED
    side[goal] = 2
    queue = np.empty(h * w, dtype=np.int64)  # the start's queue from the front, the goal's from the back
    queue[0], queue[h * w - 1] = start, goal
    a_head, a_tail, b_head, b_tail = 0, 1, h * w - 1, h * w - 2
    a_edge = b_edge = False
    while a_head < a_tail and b_head > b_tail:
        for me in (1, 2):
            if me == 1:
                i = queue[a_head]
                a_head += 1
            else:
                i = queue[b_head]
                b_head -= 1
            y, x = i // w, i % w
            if y == 0 or x == 0 or y == h - 1 or x == w - 1:
                if me == 1:
                    a_edge = True
                else:
                    b_edge = True
            for k in range(4):
                if k == 0:
                    if x + 1 >= w:
                        continue
                    j = i + 1
                elif k == 1:
                    if x == 0:
                        continue
                    j = i - 1
                elif k == 2:
                    if y + 1 >= h:
                        continue
                    j = i + w
                else:
                    if y == 0:
                        continue
                    j = i - w
                if side[j] == 0:
                    if passable[j // w, j % w]:
                        side[j] = me
                        if me == 1:
                            queue[a_tail] = j
                            a_tail += 1
                        else:
                            queue[b_tail] = j
                            b_tail -= 1
                elif side[j] != me:
                    return CONNECTED
    if a_head >= a_tail and not a_edge:
        return START_CLOSED
    if b_head <= b_tail and not b_edge:
        return GOAL_CLOSED
    return NOT_HERE


@numba.njit(cache=True, nogil=True)
def plan_kernel(passable: np.ndarray, sy: int, sx: int, gy: int, gx: int, side: np.ndarray) -> tuple[np.ndarray, int]:
    """FMM shortest path (N, 2) from (sy, sx) to (gy, gx) over ``passable`` (h, w), in its cells,
    and :func:`connected`'s verdict (``side`` as there). The start counts as passable; the march
    starts at the goal and stops once the start is settled."""
    h, w = passable.shape
    verdict = connected(passable, sy, sx, gy, gx, side)
    if verdict != CONNECTED:
        return np.empty((0, 2), dtype=np.int64), verdict
    width = w + 2 * FMM_PAD
    padded = np.zeros((h + 2 * FMM_PAD) * width, dtype=np.uint8)
    for y in range(h):
        base = (y + FMM_PAD) * width + FMM_PAD
        for x in range(w):
            padded[base + x] = passable[y, x]
    start = (sy + FMM_PAD) * width + sx + FMM_PAD
    padded[start] = 1
    sources = np.full(1, (gy + FMM_PAD) * width + gx + FMM_PAD, dtype=np.int64)
    stops = np.full(1, start, dtype=np.int64)
    field = np.empty((1, h, w), dtype=np.float32)
    at_stop = np.empty((1, 1))
    fmm_kernel(padded, width, sources, stops, True, field, 1.0, at_stop)
    path = descend(field[0], sy, sx, h * w)
    return path, CONNECTED if len(path) else NOT_HERE


@numba.njit(cache=True, nogil=True)
def block_robots(passable: np.ndarray, y0: int, x0: int, cells: np.ndarray, r: int, offsets: np.ndarray) -> None:
    """Block the ``offsets`` disc around every robot cell but robot ``r``'s (window origin (y0, x0)),
    and free robot ``r``'s own cell."""
    h, w = passable.shape
    for o in range(cells.shape[0]):
        if o == r:
            continue
        for k in range(offsets.shape[0]):
            y = cells[o, 0] + offsets[k, 0] - y0
            x = cells[o, 1] + offsets[k, 1] - x0
            if 0 <= y < h and 0 <= x < w:
                passable[y, x] = False
    y, x = cells[r, 0] - y0, cells[r, 1] - x0
    if 0 <= y < h and 0 <= x < w:
        passable[y, x] = True


def plan_path(passable: np.ndarray, start: np.ndarray, goal: np.ndarray, cell_m: float) -> np.ndarray:
    """FMM shortest path (N, 2) cells from ``start`` to ``goal`` over ``passable``; empty if none.

    The distance field is computed from the goal and stops once the start is settled (``cell_m``
    only scales distances, so the path does not depend on it).
    """
    start = np.asarray(start, dtype=np.int64)
    goal = np.asarray(goal, dtype=np.int64)
    grid = np.asarray(passable, dtype=bool)
    side = np.empty(grid.size, dtype=np.uint8)
    path, _ = plan_kernel(grid, int(start[0]), int(start[1]), int(goal[0]), int(goal[1]), side)
    return path


ROUTE_PIECE_BLOCKS = 16
"""A path read off a field of blocks is planned in pieces of this many blocks (:func:`route_path`)."""


def route_path(routes: Routes, r: int, goal: np.ndarray) -> np.ndarray:
    """Robot ``r``'s path (N, 2) to ``goal`` (window cells), from the robot's cell to the goal, read
    off its decision-time distance field; empty when the field does not reach the goal.

    A field on the window's own cells gives the path by steepest descent from the goal. A field on
    blocks of cells (``routes.block`` > 1) gives the blocks the path passes; the path itself is then
    planned on the window's cells, in pieces of :data:`ROUTE_PIECE_BLOCKS` blocks from one block's
    cell nearest its centre to the next's, each inside its blocks and the blocks around them (a
    corridor three blocks wide, in a box a few blocks across: an FMM over a small fraction of the
    window), or over the whole window when a piece finds no path in its corridor (blocks are
    passable where any of their cells is, so two blocks can touch where their cells do not)."""
    gy, gx = int(goal[0]), int(goal[1])
    field = routes.fields[r]
    k = routes.block
    if k == 1:
        return descend(field, gy, gx, field.size)[::-1]
    blocks = descend(field, gy // k, gx // k, field.size)[::-1]  # the robot's block ... the goal's
    if len(blocks) == 0:
        return blocks
    passable = routes.passable
    side = np.empty(passable.size, dtype=np.uint8)
    start = routes.robots[r].astype(np.int64)
    ends = [*range(0, max(len(blocks) - 1, 1), ROUTE_PIECE_BLOCKS), len(blocks) - 1]
    cells = [start] + [_block_anchor(passable, blocks[i], k) for i in ends[1:-1]] + [np.array([gy, gx])]
    pieces = [start[None]]
    for a, b, here, there in zip(ends[:-1], ends[1:], cells[:-1], cells[1:], strict=True):
        piece = _corridor_path(passable, blocks[a : b + 1], k, here, there, side)
        if len(piece) == 0:  # blocks that touch where their cells do not: the whole window
            path, _ = plan_kernel(passable, int(start[0]), int(start[1]), gy, gx, side)
            return path
        pieces.append(piece[1:])
    return np.concatenate(pieces)


@numba.njit(cache=True, nogil=True)
def _block_anchor(passable: np.ndarray, block: np.ndarray, k: int) -> np.ndarray:
    """The passable cell of ``block`` nearest its centre (the first in row order among equals)."""
    h, w = passable.shape
    y0, x0 = block[0] * k, block[1] * k
    centre_y, centre_x = y0 + (k - 1) / 2, x0 + (k - 1) / 2
    best = np.array([y0, x0])  # never kept for a block on a path (a block is passable where a cell is)
    nearest = np.inf
    for y in range(y0, min(y0 + k, h)):
        for x in range(x0, min(x0 + k, w)):
            d = (y - centre_y) ** 2 + (x - centre_x) ** 2
            if passable[y, x] and d < nearest:
                nearest = d
                best[0], best[1] = y, x
    return best


@numba.njit(cache=True, nogil=True)
def _corridor_path(
    passable: np.ndarray, blocks: np.ndarray, k: int, here: np.ndarray, there: np.ndarray, side: np.ndarray
) -> np.ndarray:
    """FMM path (N, 2) window cells from ``here`` to ``there`` over the passable cells of ``blocks``
    (B, 2) and the blocks around them; empty if they hold none."""
    h, w = passable.shape
    y0 = max((blocks[:, 0].min() - 1) * k, 0)
    x0 = max((blocks[:, 1].min() - 1) * k, 0)
    y1 = min((blocks[:, 0].max() + 2) * k, h)
    x1 = min((blocks[:, 1].max() + 2) * k, w)
    corridor = np.zeros((y1 - y0, x1 - x0), dtype=np.bool_)
    for b in range(blocks.shape[0]):
        for y in range(max((blocks[b, 0] - 1) * k, y0), min((blocks[b, 0] + 2) * k, y1)):
            for x in range(max((blocks[b, 1] - 1) * k, x0), min((blocks[b, 1] + 2) * k, x1)):
                corridor[y - y0, x - x0] = passable[y, x]
    path, _ = plan_kernel(corridor, here[0] - y0, here[1] - x0, there[0] - y0, there[1] - x0, side[: corridor.size])
    path[:, 0] += y0
    path[:, 1] += x0
    return path
