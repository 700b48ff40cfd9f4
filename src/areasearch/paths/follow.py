"""Following a path: how a robot gets from where it is to its long-term goal.

* planning: the FMM shortest path over the planning grid (:func:`plan_path`; :func:`descend` reads a
  path off a distance field), after a connectivity check that costs a fraction of an FMM, first in a
  window round the robot and its goal, then over the whole planning window (:func:`replan`); at a
  decision the path is read off the robot's decision-time distance field instead (:func:`route`); a
  detour round team-mates plans on a grid with their footprints blocked (:func:`block_robots`);
* following: the step kernel (:func:`act_kernel`) of every robot: arrival and the look round at the
  goal, the waits behind a team-mate and the detour requests (every ``detour_every_steps`` blocked
  tries), the robot's progress (the nearest path cell within ``progress_window_cells`` ahead), the
  check of the path ahead for newly mapped obstacles and bump marks (``check_ahead_m``), the
  line-of-sight short-term goal (``lookahead_m``) and the heading heuristic (:func:`heading_action`)
  that turns it into an action; :func:`drive` is the same for a path just planned.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numba
import numpy as np

from ..candidates import Routes
from ..geodesic import FMM_PAD, Box, fmm_kernel, region_box, window_grid
from ..world import Action
from .bumps import expire_bumps, mark_bumps
from .state import (
    DETOUR,
    F_CELL,
    F_MIN_AIM,
    F_OX,
    F_OY,
    F_TOL,
    F_VIEW,
    FORWARD,
    I_CHECK,
    I_DETOUR_EVERY,
    I_LOOK,
    I_LOOKAHEAD,
    I_MAX_BUMPS,
    I_PROGRESS_WINDOW,
    I_WAIT_LIMIT,
    I_WAIT_STEPS,
    LAST,
    LENGTH,
    OBSTACLE,
    PLANNED,
    PROGRESS,
    REPLAN,
    ROBOT,
    STAY,
    STUCK,
    TURN_LEFT,
    TURN_RIGHT,
    WAITS,
)

if TYPE_CHECKING:
    from .planner import ActionPlanner


# ---------------------------------------------------------------------------------- planning


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
def _enclosed(passable: np.ndarray, sy: int, sx: int, side: np.ndarray) -> bool:
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


_CONNECTED, _START_CLOSED, _GOAL_CLOSED, _NOT_HERE = 1, 2, 3, -1
"""Verdicts of :func:`_connected`."""


@numba.njit(cache=True, nogil=True)
def _connected(passable: np.ndarray, sy: int, sx: int, gy: int, gx: int, side: np.ndarray) -> int:
    """Whether (sy, sx) and (gy, gx) are 4-connected over ``passable`` (h, w), both ends counting
    as passable: ``_CONNECTED``; ``_START_CLOSED`` / ``_GOAL_CLOSED`` when not, the start's / the
    goal's component not touching the edge of the window (so no larger window connects them);
    ``_NOT_HERE`` when not within the window. ``side`` (h * w) uint8 receives 1 on the cells
    reached from the start (its whole component when ``_START_CLOSED``), 2 from the goal.

    Breadth-first from both ends in turn, so a disconnection costs about twice the smaller
    component and a connection about the two half-way discs, a fraction of an FMM."""
    h, w = passable.shape
    side[:] = 0
    start, goal = sy * w + sx, gy * w + gx
    side[start] = 1
    if start == goal:
        return _CONNECTED
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
                    return _CONNECTED
    if a_head >= a_tail and not a_edge:
        return _START_CLOSED
    if b_head <= b_tail and not b_edge:
        return _GOAL_CLOSED
    return _NOT_HERE


@numba.njit(cache=True, nogil=True)
def _plan_kernel(passable: np.ndarray, sy: int, sx: int, gy: int, gx: int, side: np.ndarray) -> tuple[np.ndarray, int]:
    """FMM shortest path (N, 2) from (sy, sx) to (gy, gx) over ``passable`` (h, w), in its cells,
    and :func:`_connected`'s verdict (``side`` as there). The start counts as passable; the march
    starts at the goal and stops once the start is settled."""
    h, w = passable.shape
    connected = _connected(passable, sy, sx, gy, gx, side)
    if connected != _CONNECTED:
        return np.empty((0, 2), dtype=np.int64), connected
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
    return path, _CONNECTED if len(path) else _NOT_HERE


# ---------------------------------------------------------------------------------- following


@numba.njit(cache=True, nogil=True)
def _heading(px: float, py: float, yaw: float, wx: float, wy: float, tolerance: float) -> int:
    """The heading heuristic (see :func:`heading_action`)."""
    bearing = math.atan2(wy - py, wx - px)
    error = (bearing - yaw + math.pi) % (2 * math.pi) - math.pi
    if abs(error) <= tolerance:
        return FORWARD
    return TURN_LEFT if error > 0 else TURN_RIGHT


@numba.njit(cache=True, nogil=True)
def _line_clear(los: np.ndarray, box: np.ndarray, r: int, y0: int, x0: int, y1: int, x1: int) -> bool:
    """True if every cell on the straight line between two cells (supercover sampling) lies in robot
    ``r``'s planning window ``box[r]`` (y0, y1, x0, x1) and is passable in ``los[r]``."""
    n = max(abs(y1 - y0), abs(x1 - x0)) * 2
    for k in range(1, n + 1):
        y = int(math.floor(y0 + 0.5 + (y1 - y0) * k / n))
        x = int(math.floor(x0 + 0.5 + (x1 - x0) * k / n))
        if y < box[r, 0] or y >= box[r, 1] or x < box[r, 2] or x >= box[r, 3] or not los[r, y, x]:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _nearest_frontier(
    explored: np.ndarray, occupied: np.ndarray, cy: int, cx: int, k: int, hy: int, hx: int
) -> tuple[int, int]:
    """The frontier cell (explored, free, with an unknown 4-neighbour) within ``k`` cells (Chebyshev)
    of (cy, cx) that is nearest to (hy, hx); (-1, -1) if there is none."""
    h, w = explored.shape
    best_y, best_x, best_d = -1, -1, np.inf
    for y in range(max(cy - k, 0), min(cy + k + 1, h)):
        for x in range(max(cx - k, 0), min(cx + k + 1, w)):
            if not explored[y, x] or occupied[y, x]:
                continue
            if (
                (y > 0 and not explored[y - 1, x])
                or (y < h - 1 and not explored[y + 1, x])
                or (x > 0 and not explored[y, x - 1])
                or (x < w - 1 and not explored[y, x + 1])
            ):
                d = (y - hy) ** 2 + (x - hx) ** 2
                if d < best_d:
                    best_y, best_x, best_d = y, x, d
    return best_y, best_x


@numba.njit(cache=True, nogil=True)
def _nearest_on_path(paths: np.ndarray, r: int, length: int, start: int, hy: int, hx: int, window: int) -> int:
    """Index of the path cell nearest (hy, hx), searched among the ``window`` cells from ``start``
    (``progress_window_cells``)."""
    best, best_d = start, np.inf
    for k in range(start, min(length, start + window)):
        d = (paths[r, k, 0] - hy) ** 2 + (paths[r, k, 1] - hx) ** 2
        if d < best_d:
            best, best_d = k, d
    return best


@numba.njit(cache=True, nogil=True)
def _newly_blocked(
    paths: np.ndarray,
    r: int,
    start: int,
    stop: int,
    planned: int,
    occupied_at: np.ndarray,
    bumps_at: np.ndarray,
    offsets: np.ndarray,
) -> bool:
    """True if, since the map version ``planned``, an obstacle was mapped within the footprint disc
    (``offsets``) of a cell of path[start:stop], or a bump marked such a cell."""
    h, w = occupied_at.shape
    for i in range(start, stop):
        y, x = paths[r, i, 0], paths[r, i, 1]
        if bumps_at[y, x] > planned:
            return True
        for k in range(offsets.shape[0]):
            ny, nx = y + offsets[k, 0], x + offsets[k, 1]
            if 0 <= ny < h and 0 <= nx < w and 2 * occupied_at[ny, nx] > planned:
                return True
    return False


@numba.njit(cache=True, nogil=True)
def _short_term_goal(
    paths: np.ndarray,
    r: int,
    length: int,
    los: np.ndarray,
    box: np.ndarray,
    hy: int,
    hx: int,
    i: int,
    lookahead: int,
    px: float,
    py: float,
    fparams: np.ndarray,
) -> int:
    """Index of the short-term goal: the farthest path cell at most ``lookahead`` cells ahead of
    ``i`` that the robot sees in a straight passable line (so it never cuts a corner), at least i+1;
    then, while that cell's centre is nearer than ``fparams[F_MIN_AIM]`` to the robot's centre
    (px, py), the next path cell (the heading to a point a few centimetres away says nothing of the
    path)."""
    last = length - 1
    j = min(i + 1, last)
    for k in range(min(i + lookahead, last), i + 1, -1):
        if _line_clear(los, box, r, hy, hx, paths[r, k, 0], paths[r, k, 1]):
            j = k
            break
    ox, oy, cell_m, near = fparams[F_OX], fparams[F_OY], fparams[F_CELL], fparams[F_MIN_AIM]
    while j < last:
        wx = ox + (paths[r, j, 1] + 0.5) * cell_m
        wy = oy + (paths[r, j, 0] + 0.5) * cell_m
        if math.hypot(wx - px, wy - py) >= near:
            break
        j += 1
    return j


@numba.njit(cache=True, nogil=True)
def drive(
    r: int,
    poses: np.ndarray,
    paths: np.ndarray,
    state: np.ndarray,
    los: np.ndarray,
    los_box: np.ndarray,
    fparams: np.ndarray,
    iparams: np.ndarray,
) -> int:
    """The action of robot ``r`` on a path it has just planned."""
    ox, oy, cell_m = fparams[F_OX], fparams[F_OY], fparams[F_CELL]
    px, py, yaw = poses[r, 0], poses[r, 1], poses[r, 2]
    hy = int(math.floor((py - oy) / cell_m))
    hx = int(math.floor((px - ox) / cell_m))
    length = state[r, LENGTH]
    best = _nearest_on_path(paths, r, length, 0, hy, hx, iparams[I_PROGRESS_WINDOW])
    state[r, PROGRESS] = best
    j = _short_term_goal(paths, r, length, los, los_box, hy, hx, best, iparams[I_LOOKAHEAD], px, py, fparams)
    wx = ox + (paths[r, j, 1] + 0.5) * cell_m
    wy = oy + (paths[r, j, 0] + 0.5) * cell_m
    action = _heading(px, py, yaw, wx, wy, fparams[F_TOL])
    state[r, LAST] = action
    return action


@numba.njit(cache=True, nogil=True)
def act_kernel(
    poses: np.ndarray,
    blocked_by: np.ndarray,
    goals: np.ndarray,
    tolerances: np.ndarray,
    paths: np.ndarray,
    state: np.ndarray,
    unreachable: np.ndarray,
    reached: np.ndarray,
    settled: np.ndarray,
    explored: np.ndarray,
    occupied: np.ndarray,
    occupied_at: np.ndarray,
    version: int,
    now: int,
    bumps: np.ndarray,
    bump_count: np.ndarray,
    bumps_at: np.ndarray,
    bump_log: np.ndarray,
    bump_ptr: np.ndarray,
    offsets: np.ndarray,
    los: np.ndarray,
    los_box: np.ndarray,
    fparams: np.ndarray,
    iparams: np.ndarray,
    actions: np.ndarray,
    need: np.ndarray,
) -> int:
    """One step of every robot (see :meth:`ActionPlanner.act`): the bump memory brought up to date
    (:func:`~areasearch.paths.bumps.expire_bumps`, :func:`~areasearch.paths.bumps.mark_bumps`), then
    per robot arrival, waits and the path ahead; returns how many robots need a
    re-plan or a detour from Python (``need``), their ``actions`` being STAY until then.

    ``version`` is the map version of this step (bumps marked now are newer than paths planned
    before this step, not newer than re-plans of this step), ``now`` the world's step count."""
    n = poses.shape[0]
    ox, oy, cell_m = fparams[F_OX], fparams[F_OY], fparams[F_CELL]
    expire_bumps(now, bumps, bump_count, bumps_at, bump_log, bump_ptr)
    mark_bumps(poses, blocked_by, version, now, fparams, iparams, bumps, bump_count, bumps_at, bump_log, bump_ptr)
    pending = 0
    for r in range(n):
        actions[r] = STAY
        need[r] = 0
        action = STAY
        px, py, yaw = poses[r, 0], poses[r, 1], poses[r, 2]
        hy = int(math.floor((py - oy) / cell_m))
        hx = int(math.floor((px - ox) / cell_m))
        b = blocked_by[r]
        if goals[r, 0] >= 0 and not unreachable[r]:
            gx = ox + (goals[r, 1] + 0.5) * cell_m
            gy = oy + (goals[r, 0] + 0.5) * cell_m
            if math.hypot(gx - px, gy - py) <= tolerances[r]:
                # arrived: face the nearest frontier cell near the goal, then stay
                reached[r] = True
                if not settled[r]:
                    fy, fx = _nearest_frontier(explored, occupied, goals[r, 0], goals[r, 1], iparams[I_LOOK], hy, hx)
                    if fy < 0:
                        settled[r] = True
                    else:
                        wx = ox + (fx + 0.5) * cell_m
                        wy = oy + (fy + 0.5) * cell_m
                        action = _heading(px, py, yaw, wx, wy, fparams[F_VIEW])
                        if action == FORWARD:
                            settled[r] = True
                            action = STAY
            else:
                moved = state[r, LAST] == FORWARD and b == 0
                bumped = b == OBSTACLE
                if moved:
                    state[r, STUCK] = 0
                    state[r, WAITS] = 0
                else:
                    state[r, STUCK] += 1 if bumped else 0
                    if b == ROBOT:
                        state[r, WAITS] += 1
                waits = state[r, WAITS]
                if state[r, STUCK] > iparams[I_MAX_BUMPS] or waits > iparams[I_WAIT_LIMIT]:
                    unreachable[r] = True
                elif b == ROBOT and waits <= iparams[I_WAIT_STEPS]:
                    pass  # give the other robot a moment to pass (STAY)
                elif b == ROBOT and (waits - iparams[I_WAIT_STEPS] - 1) % iparams[I_DETOUR_EVERY] == 0:
                    need[r] = DETOUR  # go round the team-mates if there is a way; else wait
                else:
                    length = state[r, LENGTH]
                    target = -1
                    if length > 0 and not bumped:
                        best = _nearest_on_path(
                            paths, r, length, state[r, PROGRESS], hy, hx, iparams[I_PROGRESS_WINDOW]
                        )
                        state[r, PROGRESS] = best
                        stop = min(best + iparams[I_CHECK], length)
                        if not _newly_blocked(paths, r, best, stop, state[r, PLANNED], occupied_at, bumps_at, offsets):
                            target = _short_term_goal(
                                paths, r, length, los, los_box, hy, hx, best, iparams[I_LOOKAHEAD], px, py, fparams
                            )
                    if target < 0:
                        need[r] = REPLAN
                    else:
                        wx = ox + (paths[r, target, 1] + 0.5) * cell_m
                        wy = oy + (paths[r, target, 0] + 0.5) * cell_m
                        action = _heading(px, py, yaw, wx, wy, fparams[F_TOL])
        if need[r] != 0:
            pending += 1
        actions[r] = action
        state[r, LAST] = action
    return pending


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


# ---------------------------------------------------------------------------------- API


def plan_path(passable: np.ndarray, start: np.ndarray, goal: np.ndarray, cell_m: float) -> np.ndarray:
    """FMM shortest path (N, 2) cells from ``start`` to ``goal`` over ``passable``; empty if none.

    The distance field is computed from the goal and stops once the start is settled (``cell_m``
    only scales distances, so the path does not depend on it).
    """
    start = np.asarray(start, dtype=np.int64)
    goal = np.asarray(goal, dtype=np.int64)
    grid = np.asarray(passable, dtype=bool)
    side = np.empty(grid.size, dtype=np.uint8)
    path, _ = _plan_kernel(grid, int(start[0]), int(start[1]), int(goal[0]), int(goal[1]), side)
    return path


def heading_action(pose: np.ndarray, waypoint_xy: tuple[float, float] | np.ndarray, tolerance_rad: float) -> int:
    """FORWARD if the waypoint lies within ``tolerance_rad`` of the heading, else turn towards it."""
    bearing = math.atan2(waypoint_xy[1] - pose[1], waypoint_xy[0] - pose[0])
    error = (bearing - pose[2] + math.pi) % (2 * math.pi) - math.pi
    if abs(error) <= tolerance_rad:
        return int(Action.FORWARD)
    return int(Action.TURN_LEFT if error > 0 else Action.TURN_RIGHT)


# ---------------------------------------------------------------------------------- re-plans (Python)


def store_path(planner: ActionPlanner, r: int, path: np.ndarray, box: Box, passable: np.ndarray, version: int) -> None:
    """Make ``path`` (global cells) robot ``r``'s path, planned on ``passable`` (the grid of ``box``)
    at map version ``version``; the path buffer doubles when the path does not fit."""
    if len(path) > planner._paths.shape[1]:
        grown = np.zeros((len(planner.goals), max(len(path), 2 * planner._paths.shape[1]), 2), dtype=np.int64)
        grown[:, : planner._paths.shape[1]] = planner._paths
        planner._paths = grown
    planner._paths[r, : len(path)] = path
    planner._state[r, LENGTH] = len(path)
    planner._state[r, PROGRESS] = 0
    planner._state[r, PLANNED] = version
    planner._los[r, box.y0 : box.y1, box.x0 : box.x1] = passable
    planner._los_box[r] = (box.y0, box.y1, box.x0, box.x1)


def planning_grid(planner: ActionPlanner, box: Box, cells: np.ndarray) -> np.ndarray:
    """The planning grid of ``box`` now: known obstacles inflated, unknown cells passable near
    frontiers, the collision map blocked, the robots' cells free."""
    mapper = planner.world.mapper
    assert mapper is not None
    memory = planner._bump_memory
    passable, _ = window_grid(
        mapper.explored,
        mapper.occupied,
        box,
        planner._cell_m,
        planner._radius_m,
        unknown_margin_m=planner.config.unknown_margin_m,
        keep_free=cells,
        impassable=memory.mask if memory.live else None,
        inflated=planner._inflated.update(mapper.occupied),
    )
    return passable


def route(planner: ActionPlanner, r: int, goal: np.ndarray, routes: Routes) -> None:
    """Robot ``r``'s path to ``goal`` read off its decision-time distance field (goal -> robot
    by steepest descent, reversed); left to :meth:`ActionPlanner.act` to plan if the goal is outside
    the window."""
    box = routes.box
    local = goal - box.origin
    if not (0 <= local[0] < box.shape[0] and 0 <= local[1] < box.shape[1]):
        return
    field = routes.fields[r]
    back = descend(field, int(local[0]), int(local[1]), field.size)
    if len(back) == 0:
        planner.unreachable[r] = True
        return
    store_path(planner, r, back[::-1] + box.origin, box, routes.passable, planner._version())


def replan(planner: ActionPlanner, r: int, cells: np.ndarray, avoid_robots: bool) -> bool:
    """FMM path for robot ``r``: first in a window around the robot and its goal grown by
    ``local_margin_m`` (cheap), then, if that finds none, over the whole planning window. A
    detour round team-mates (``avoid_robots``) is sought in the local window only.

    A connectivity check comes first (:func:`_connected`), so a goal that cannot be reached
    costs no FMM; a robot found walled in (by obstacles and bump marks) is recorded in
    :attr:`ActionPlanner.walled_in`, so that its caller can pick a goal it can reach."""
    planner.replans += 1
    mapper = planner.world.mapper
    assert mapper is not None
    goal, here = planner.goals[r], cells[r]
    m = planner._local_margin
    h, w = mapper.shape
    planner.walled_in[r] = None
    if not avoid_robots and not (abs(goal[0] - here[0]) <= m and abs(goal[1] - here[1]) <= m):
        # a goal far away: first make sure the robot is not walled in (by bump marks, mostly),
        # which a small window round the robot shows at a fraction of the cost of the others
        near = Box(max(here[0] - m, 0), min(here[0] + m + 1, h), max(here[1] - m, 0), min(here[1] + m + 1, w))
        passable = planning_grid(planner, near, cells)
        side = np.empty(passable.size, dtype=np.uint8)
        if _enclosed(passable, here[0] - near.y0, here[1] - near.x0, side):
            planner.walled_in[r] = (near, side.reshape(passable.shape) == 1)
            return False
    box = Box(
        max(min(here[0], goal[0]) - m, 0),
        min(max(here[0], goal[0]) + m + 1, h),
        max(min(here[1], goal[1]) - m, 0),
        min(max(here[1], goal[1]) + m + 1, w),
    )
    while True:
        passable = planning_grid(planner, box, cells)
        if avoid_robots:
            block_robots(passable, box.y0, box.x0, cells, r, planner._robot_offsets)
        side = np.empty(passable.size, dtype=np.uint8)
        path, verdict = _plan_kernel(
            passable, here[0] - box.y0, here[1] - box.x0, goal[0] - box.y0, goal[1] - box.x0, side
        )
        if verdict == _CONNECTED:
            store_path(planner, r, path + box.origin, box, passable, planner._version() + 1)
            return True
        if verdict == _START_CLOSED and not avoid_robots:
            planner.walled_in[r] = (box, side.reshape(passable.shape) == 1)
        if verdict != _NOT_HERE or avoid_robots:
            return False  # walled in, the goal walled in, or no detour nearby
        goals = planner.goals[planner.goals[:, 0] >= 0]
        whole = region_box(mapper.explored, planner._window_margin, np.concatenate([cells, goals]))
        if whole == box:
            return False
        box = whole
