"""Pipeline stage "paths": the FMM action planner (DA-HGNN "Action Planner and Execution", after NCM).

Every robot follows its long-term goal with the planner of Ye et al. (CVPR 2022) that DA-HGNN
reuses: the shortest path from the robot to the goal by the Fast Marching Method on the current map
(known obstacles inflated by the footprint, unknown cells traversable), sub-sampled into waypoints;
the short-term goal is the waypoint ``lookahead_m`` ahead along the path, and the heading heuristic
of Chen et al. (2021) turns it into a primitive action: FORWARD when the robot faces the short-term
goal (within half a turn step), otherwise TURN_LEFT / TURN_RIGHT towards it.

Behaviour that users of frontier explorers asked for (see REFERENCE-SETTINGS.md):

* **first path**: at a decision the path to the new goal is read off the robot's distance field that
  candidate extraction computed anyway (:class:`~areasearch.candidates.Routes`), so a new goal
  costs no extra FMM;
* **re-planning**: a robot re-plans after it bumps into something and when the mapper marks an
  obstacle within a footprint of the next ``check_ahead_m`` of its path that was not on the map when
  the path was planned (``Mapper.occupied_at``; an old obstacle the path was planned beside is no
  reason to re-plan), by FMM from the goal that stops once it reaches the robot, first in a window
  around the robot and its goal, then over the whole planning window;
* **blocked by a robot**: a robot blocked by a team-mate waits (STAY) ``robot_wait_steps`` steps
  for it to pass, then re-plans treating the other robots' footprints as obstacles and goes round
  them (a detour is sought every 5th blocked try); if they block every way it keeps waiting, and
  after ``robot_wait_limit`` blocked tries without moving the goal counts as unreachable (so the
  caller sends the robot elsewhere instead of leaving two robots face to face in a corridor);
* **arrived**: within ``goal_tolerance_m`` of its goal a robot turns to face the nearest frontier
  cell within ``look_radius_m`` of the goal (so a frontier is looked at, not only reached) and then
  stays (STAY, :attr:`ActionPlanner.settled`) until it gets a new goal: it never wanders off before
  the next decision;
* **bumped**: a FORWARD blocked by an obstacle the robot has not mapped (beside or behind its 90°
  view) marks the cells its centre would have crossed as impassable for planning (a collision map,
  as in Chaplot et al. 2020, :attr:`ActionPlanner.bumps`) for ``bump_memory_steps`` steps, and it
  re-plans; after ``max_bumps`` such bumps without moving the goal counts as unreachable. The
  high-level environment plans the candidates' distances round the same collision map, so a goal
  it offers is one the planner can reach;
* **unreachable**: when no path exists the robot stays and :attr:`ActionPlanner.unreachable` says so;
  the caller (the high-level environment) then gives it another goal;
* **giving way** (not in the paper): when a robot's detour round a blocking team-mate has not helped
  5 steps later, the team-mate, if it has no goal, drives to the nearest cell off the other's way;
  if both block each other, the one of higher index does so, waits there, then goes on
  (:meth:`ActionPlanner._give_way`). Without it, two robots that need one narrow passage in
  opposite ways could block each other for the rest of an episode;
* **primitive search** (not in the paper): a FORWARD that would bump into a mapped obstacle (by the
  world's own rule: the cells every half cell along the move within the clearance threshold of an
  obstacle) is replaced by a plan of primitive moves, A* over the poses FORWARD and the turns reach
  (:func:`_primitive_search`), on the space the map shows free, to the goal if it lies within
  ``primitive_search_m``, else to the path that far ahead. Without it, the heading heuristic could
  not enter a way in barely wider than the robot (it cut the corner and bumped, and its bump marks
  closed the way in on the planning grid).

Speed: everything a step needs for all robots (bump marks, arrival and look-around, waits, path
following with the check ahead and the line-of-sight short-term goal, the heading heuristic) is one
numba kernel call; only re-plans return to Python, and those build the planning grid of their window
alone (:func:`~areasearch.geodesic.window_grid`) and run the FMM and the descent in one kernel.

Paths are (N, 2) cell arrays from the robot's cell to the goal cell; distances in metres.
"""

from __future__ import annotations

import heapq
import math

import numba
import numpy as np

from .candidates import Routes
from .config import PathConfig
from .geodesic import (
    _PAD,
    Box,
    InflatedObstacles,
    _fmm_kernel,
    _inflate_kernel,
    clearance_threshold_m,
    disc_offsets,
    distance_field,
    region_box,
    window_grid,
)
from .world import BLOCKED_BY_OBSTACLE, BLOCKED_BY_ROBOT, Action, World, _wrap

_FORWARD, _TURN_LEFT, _TURN_RIGHT, _STAY = (
    int(Action.FORWARD),
    int(Action.TURN_LEFT),
    int(Action.TURN_RIGHT),
    int(Action.STAY),
)
_OBSTACLE, _ROBOT = BLOCKED_BY_OBSTACLE, BLOCKED_BY_ROBOT
_REPLAN, _DETOUR = 1, 2
"""What a robot needs from Python after the step kernel (``ActionPlanner._need``)."""
_PROGRESS, _LENGTH, _PLANNED, _STUCK, _WAITS, _LAST = range(6)
"""Columns of ``ActionPlanner._state`` (R, 6) int64: path cell nearest the robot, path length
(0: no path), map version the path was planned on, bumps and robot-blocked tries without moving,
last action."""
_F_OX, _F_OY, _F_CELL, _F_TOL, _F_VIEW, _F_BUMP0, _F_BUMP1 = range(7)
_I_CHECK, _I_LOOKAHEAD, _I_LOOK, _I_MAX_BUMPS, _I_WAIT_LIMIT, _I_WAIT_STEPS, _I_BUMP_MEMORY = range(7)
_BUMP_SAMPLES = 6
_MAX_MOVES = 48
"""Longest plan a primitive search returns, actions."""
"""Points along a blocked forward move whose cells a bump marks."""


# ---------------------------------------------------------------------------------- kernels


@numba.njit(cache=True, nogil=True)
def _descend(field: np.ndarray, start_y: int, start_x: int, max_len: int) -> np.ndarray:
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
    width = w + 2 * _PAD
    padded = np.zeros((h + 2 * _PAD) * width, dtype=np.uint8)
    for y in range(h):
        base = (y + _PAD) * width + _PAD
        for x in range(w):
            padded[base + x] = passable[y, x]
    start = (sy + _PAD) * width + sx + _PAD
    padded[start] = 1
    sources = np.full(1, (gy + _PAD) * width + gx + _PAD, dtype=np.int64)
    stops = np.full(1, start, dtype=np.int64)
    field = np.empty((1, h, w), dtype=np.float32)
    at_stop = np.empty((1, 1))
    _fmm_kernel(padded, width, sources, stops, True, field, 1.0, at_stop)
    path = _descend(field[0], sy, sx, h * w)
    return path, _CONNECTED if len(path) else _NOT_HERE


@numba.njit(cache=True, nogil=True)
def _heading(px: float, py: float, yaw: float, wx: float, wy: float, tolerance: float) -> int:
    """The heading heuristic (see :func:`heading_action`)."""
    bearing = math.atan2(wy - py, wx - px)
    error = (bearing - yaw + math.pi) % (2 * math.pi) - math.pi
    if abs(error) <= tolerance:
        return _FORWARD
    return _TURN_LEFT if error > 0 else _TURN_RIGHT


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
def _nearest_on_path(paths: np.ndarray, r: int, length: int, start: int, hy: int, hx: int) -> int:
    """Index of the path cell nearest (hy, hx), searched from ``start`` a little ahead."""
    best, best_d = start, np.inf
    for k in range(start, min(length, start + 40)):
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
    paths: np.ndarray, r: int, length: int, los: np.ndarray, box: np.ndarray, hy: int, hx: int, i: int, lookahead: int
) -> int:
    """Index of the short-term goal: the farthest path cell at most ``lookahead`` cells ahead of
    ``i`` that the robot sees in a straight passable line (so it never cuts a corner), at least i+1."""
    last = length - 1
    for j in range(min(i + lookahead, last), i + 1, -1):
        if _line_clear(los, box, r, hy, hx, paths[r, j, 0], paths[r, j, 1]):
            return j
    return min(i + 1, last)


@numba.njit(cache=True, nogil=True)
def _drive(
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
    ox, oy, cell_m = fparams[_F_OX], fparams[_F_OY], fparams[_F_CELL]
    px, py, yaw = poses[r, 0], poses[r, 1], poses[r, 2]
    hy = int(math.floor((py - oy) / cell_m))
    hx = int(math.floor((px - ox) / cell_m))
    length = state[r, _LENGTH]
    best = _nearest_on_path(paths, r, length, 0, hy, hx)
    state[r, _PROGRESS] = best
    j = _short_term_goal(paths, r, length, los, los_box, hy, hx, best, iparams[_I_LOOKAHEAD])
    wx = ox + (paths[r, j, 1] + 0.5) * cell_m
    wy = oy + (paths[r, j, 0] + 0.5) * cell_m
    action = _heading(px, py, yaw, wx, wy, fparams[_F_TOL])
    state[r, _LAST] = action
    return action


@numba.njit(cache=True, nogil=True)
def _act_kernel(
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
    """One step of every robot (see :meth:`ActionPlanner.act`); returns how many robots need a
    re-plan or a detour from Python (``need``), their ``actions`` being STAY until then.

    ``version`` is the map version of this step (bumps marked now are newer than paths planned
    before this step, not newer than re-plans of this step), ``now`` the world's step count."""
    n = poses.shape[0]
    gh, gw = bumps.shape
    ox, oy, cell_m = fparams[_F_OX], fparams[_F_OY], fparams[_F_CELL]
    # expired bump marks
    while bump_ptr[0] < bump_ptr[1] and bump_log[bump_ptr[0], 0] <= now:
        y, x = bump_log[bump_ptr[0], 1], bump_log[bump_ptr[0], 2]
        bump_ptr[0] += 1
        bump_count[y, x] -= 1
        if bump_count[y, x] == 0:
            bumps[y, x] = False
            bumps_at[y, x] = 0
    # new bump marks: the cells the centre of a robot whose FORWARD an obstacle blocked would have crossed
    for r in range(n):
        if blocked_by[r] != _OBSTACLE:
            continue
        px, py = poses[r, 0], poses[r, 1]
        hy = int(math.floor((py - oy) / cell_m))
        hx = int(math.floor((px - ox) / cell_m))
        c, s = math.cos(poses[r, 2]), math.sin(poses[r, 2])
        d0, d1 = fparams[_F_BUMP0], fparams[_F_BUMP1]
        for k in range(_BUMP_SAMPLES):
            d = d1 if k == _BUMP_SAMPLES - 1 else d0 + k * (d1 - d0) / (_BUMP_SAMPLES - 1)
            y = int(math.floor((py + d * s - oy) / cell_m))
            x = int(math.floor((px + d * c - ox) / cell_m))
            if (y == hy and x == hx) or y < 0 or x < 0 or y >= gh or x >= gw:
                continue
            bumps[y, x] = True
            bump_count[y, x] += 1
            bumps_at[y, x] = version
            t = bump_ptr[1]
            bump_log[t, 0] = now + iparams[_I_BUMP_MEMORY]
            bump_log[t, 1] = y
            bump_log[t, 2] = x
            bump_ptr[1] = t + 1
    pending = 0
    for r in range(n):
        actions[r] = _STAY
        need[r] = 0
        action = _STAY
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
                    fy, fx = _nearest_frontier(explored, occupied, goals[r, 0], goals[r, 1], iparams[_I_LOOK], hy, hx)
                    if fy < 0:
                        settled[r] = True
                    else:
                        wx = ox + (fx + 0.5) * cell_m
                        wy = oy + (fy + 0.5) * cell_m
                        action = _heading(px, py, yaw, wx, wy, fparams[_F_VIEW])
                        if action == _FORWARD:
                            settled[r] = True
                            action = _STAY
            else:
                moved = state[r, _LAST] == _FORWARD and b == 0
                bumped = b == _OBSTACLE
                if moved:
                    state[r, _STUCK] = 0
                    state[r, _WAITS] = 0
                else:
                    state[r, _STUCK] += 1 if bumped else 0
                    if b == _ROBOT:
                        state[r, _WAITS] += 1
                waits = state[r, _WAITS]
                if state[r, _STUCK] > iparams[_I_MAX_BUMPS] or waits > iparams[_I_WAIT_LIMIT]:
                    unreachable[r] = True
                elif b == _ROBOT and waits <= iparams[_I_WAIT_STEPS]:
                    pass  # give the other robot a moment to pass (STAY)
                elif b == _ROBOT and (waits - iparams[_I_WAIT_STEPS]) % 5 == 1:
                    need[r] = _DETOUR  # go round the team-mates if there is a way; else wait
                else:
                    length = state[r, _LENGTH]
                    target = -1
                    if length > 0 and not bumped:
                        best = _nearest_on_path(paths, r, length, state[r, _PROGRESS], hy, hx)
                        state[r, _PROGRESS] = best
                        stop = min(best + iparams[_I_CHECK], length)
                        if not _newly_blocked(paths, r, best, stop, state[r, _PLANNED], occupied_at, bumps_at, offsets):
                            target = _short_term_goal(
                                paths, r, length, los, los_box, hy, hx, best, iparams[_I_LOOKAHEAD]
                            )
                    if target < 0:
                        need[r] = _REPLAN
                    else:
                        wx = ox + (paths[r, target, 1] + 0.5) * cell_m
                        wy = oy + (paths[r, target, 0] + 0.5) * cell_m
                        action = _heading(px, py, yaw, wx, wy, fparams[_F_TOL])
        if need[r] != 0:
            pending += 1
        actions[r] = action
        state[r, _LAST] = action
    return pending


@numba.njit(cache=True, nogil=True)
def _forward_clear(
    blocked: np.ndarray,
    y0: int,
    x0: int,
    ox: float,
    oy: float,
    cell_m: float,
    x: float,
    y: float,
    yaw: float,
    forward_m: float,
    others: np.ndarray,
    min_sep2: float,
) -> bool:
    """Would a FORWARD from (x, y, yaw) pass, by the world's own rule (``world._move_kernel``: the
    cells of points every half cell along the move are free, the end pose keeps ``min_sep2`` from
    every other robot), on ``blocked`` (a window with first cell (y0, x0); outside it counts as blocked)?"""
    h, w = blocked.shape
    n_sub = int(math.ceil(forward_m / (0.5 * cell_m)))
    c, s = math.cos(yaw), math.sin(yaw)
    for k in range(1, n_sub + 1):
        f = forward_m * k / n_sub
        ix = int(math.floor((x + c * f - ox) / cell_m)) - x0
        iy = int(math.floor((y + s * f - oy) / cell_m)) - y0
        if ix < 0 or iy < 0 or iy >= h or ix >= w or blocked[iy, ix]:
            return False
    nx, ny = x + c * forward_m, y + s * forward_m
    for o in range(others.shape[0]):
        if (others[o, 0] - nx) ** 2 + (others[o, 1] - ny) ** 2 < min_sep2:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _bumps_ahead(
    occupied: np.ndarray,
    radius_cells: float,
    ox: float,
    oy: float,
    cell_m: float,
    poses: np.ndarray,
    actions: np.ndarray,
    forward_m: float,
    moves_len: np.ndarray,
    moves_failed: np.ndarray,
    failed_before: int,
    out: np.ndarray,
) -> bool:
    """``out[r]``: robot ``r``'s FORWARD would cross a cell within ``radius_cells`` (the clearance
    threshold, as :func:`~areasearch.geodesic.disc_offsets` counts it) of a mapped obstacle, so the
    world would block it; robots that follow a plan of moves or whose last search failed after step
    ``failed_before`` are not checked. True if some robot needs :meth:`ActionPlanner._primitive_moves`
    (a plan to follow or a bump ahead)."""
    h, w = occupied.shape
    n_sub = int(math.ceil(forward_m / (0.5 * cell_m)))
    reach = int(math.floor(radius_cells))
    r2 = radius_cells * radius_cells
    ys = np.empty(n_sub, dtype=np.int64)
    xs = np.empty(n_sub, dtype=np.int64)
    anything = False
    for r in range(poses.shape[0]):
        out[r] = False
        if moves_len[r] > 0:
            anything = True
            continue
        if actions[r] != _FORWARD or moves_failed[r] > failed_before:
            continue
        c, s = math.cos(poses[r, 2]), math.sin(poses[r, 2])
        m = 0
        for k in range(1, n_sub + 1):  # the cells the world checks, as world._move_kernel samples them
            f = forward_m * k / n_sub
            ix = int(math.floor((poses[r, 0] + c * f - ox) / cell_m))
            iy = int(math.floor((poses[r, 1] + s * f - oy) / cell_m))
            if m == 0 or ys[m - 1] != iy or xs[m - 1] != ix:
                ys[m] = iy
                xs[m] = ix
                m += 1
        y0, y1 = max(min(ys[0], ys[m - 1]) - reach, 0), min(max(ys[0], ys[m - 1]) + reach + 1, h)
        x0, x1 = max(min(xs[0], xs[m - 1]) - reach, 0), min(max(xs[0], xs[m - 1]) + reach + 1, w)
        for y in range(y0, y1):
            for x in range(x0, x1):
                if occupied[y, x]:
                    for k in range(m):
                        if (ys[k] - y) ** 2 + (xs[k] - x) ** 2 <= r2:
                            out[r] = True
                            break
                if out[r]:
                    break
            if out[r]:
                anything = True
                break
    return anything


@numba.njit(cache=True, nogil=True)
def _primitive_search(
    blocked: np.ndarray,
    y0: int,
    x0: int,
    ox: float,
    oy: float,
    cell_m: float,
    pose: np.ndarray,
    forward_m: float,
    turn_rad: float,
    others: np.ndarray,
    min_sep2: float,
    gx: float,
    gy: float,
    tolerance: float,
    max_expand: int,
    out: np.ndarray,
) -> int:
    """Shortest sequence of primitive actions (FORWARD, TURN_LEFT, TURN_RIGHT; one step each) that
    brings a robot at ``pose`` within ``tolerance`` of (gx, gy) without a blocked move, by A* over
    the poses the primitives reach (exactly as the world moves a robot; poses in one cell with one
    heading count as one). Writes the actions to ``out`` and returns how many, or -1 if none is
    found within ``max_expand`` expansions or ``len(out)`` actions."""
    h, w = blocked.shape
    n_head = int(round(2.0 * math.pi / turn_rad))
    cap = 3 * max_expand + 1
    xs = np.empty(cap)
    ys = np.empty(cap)
    yaws = np.empty(cap)
    head = np.empty(cap, dtype=np.int64)
    depth = np.empty(cap, dtype=np.int64)
    parent = np.empty(cap, dtype=np.int64)
    move = np.empty(cap, dtype=np.int64)
    seen = np.zeros((h, w, n_head), dtype=np.bool_)
    xs[0], ys[0], yaws[0], head[0], depth[0], parent[0], move[0] = pose[0], pose[1], pose[2], 0, 0, -1, -1
    iy = int(math.floor((pose[1] - oy) / cell_m)) - y0
    ix = int(math.floor((pose[0] - ox) / cell_m)) - x0
    if not (0 <= iy < h and 0 <= ix < w):
        return -1
    seen[iy, ix, 0] = True
    heap = [(0.0, 0)]
    n = 1
    expanded = 0
    found = -1
    while len(heap) > 0 and expanded < max_expand:
        _, i = heapq.heappop(heap)
        expanded += 1
        if depth[i] >= out.shape[0]:
            continue
        for a in (_FORWARD, _TURN_LEFT, _TURN_RIGHT):
            x, y, yaw, k = xs[i], ys[i], yaws[i], head[i]
            if a == _FORWARD:
                if not _forward_clear(blocked, y0, x0, ox, oy, cell_m, x, y, yaw, forward_m, others, min_sep2):
                    continue
                x += math.cos(yaw) * forward_m
                y += math.sin(yaw) * forward_m
            elif a == _TURN_LEFT:
                yaw = _wrap(yaw + turn_rad)
                k = (k + 1) % n_head
            else:
                yaw = _wrap(yaw - turn_rad)
                k = (k - 1) % n_head
            cy = int(math.floor((y - oy) / cell_m)) - y0
            cx = int(math.floor((x - ox) / cell_m)) - x0
            if seen[cy, cx, k]:
                continue
            seen[cy, cx, k] = True
            xs[n], ys[n], yaws[n], head[n], depth[n], parent[n], move[n] = x, y, yaw, k, depth[i] + 1, i, a
            d = math.hypot(gx - x, gy - y)
            if d <= tolerance:
                found = n
                break
            # admissible: the forward moves still needed, whatever the turns
            heapq.heappush(heap, (float(depth[n] + math.ceil((d - tolerance) / forward_m - 1e-9)), n))
            n += 1
        if found >= 0:
            break
    if found < 0:
        return -1
    length = depth[found]
    j = found
    while j > 0:
        out[depth[j] - 1] = move[j]
        j = parent[j]
    return length


@numba.njit(cache=True, nogil=True)
def _block_robots(passable: np.ndarray, y0: int, x0: int, cells: np.ndarray, r: int, offsets: np.ndarray) -> None:
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


class ActionPlanner:
    """Drives every robot of a :class:`World` towards its long-term goal, one primitive action a step.

    Call :meth:`set_goals` at each decision, then :meth:`act` every step.
    """

    def __init__(self, config: PathConfig, world: World) -> None:
        self.config = config
        self.world = world
        n = world.config.num_robots
        self.goals = np.full((n, 2), -1, dtype=np.int64)
        self.tolerances_m = np.full(n, config.goal_tolerance_m)
        self.unreachable = np.zeros(n, dtype=bool)
        self.reached = np.zeros(n, dtype=bool)
        self.settled = np.zeros(n, dtype=bool)
        """Arrived and looked at what there was to see around the goal."""
        self.walled_in: list[tuple[Box, np.ndarray] | None] = [None] * n
        """Per robot, after a re-plan that found it walled in (obstacles and bump marks all round):
        the window and the (h, w) mask of the cells it can still reach; else None."""
        self.replans = 0
        scene = world.scene
        assert scene is not None
        cell_m = scene.cell_m
        self._cell_m = cell_m
        radius = world.config.robot.radius_m
        self._radius_m = radius
        self._clearance_cells = clearance_threshold_m(cell_m, radius) / cell_m
        self._offsets = disc_offsets(self._clearance_cells)
        self._inflated = InflatedObstacles(scene.shape, cell_m, radius)
        self._robot_offsets = disc_offsets(2 * radius / cell_m)  # robots closer than two radii overlap
        self._local_margin = round(config.local_margin_m / cell_m)
        self._window_margin = int(math.floor(config.unknown_margin_m / cell_m + 1e-9)) + 1
        self._fparams = np.array(
            [
                scene.origin_xy[0],
                scene.origin_xy[1],
                cell_m,
                world.config.robot.turn_rad / 2 + 1e-6,  # FORWARD within half a turn step
                math.radians(world.config.camera.hfov_deg) / 4,  # looking at a frontier: within half the view
                cell_m / 2,
                world.config.robot.forward_m,
            ]
        )
        self._iparams = np.array(
            [
                max(1, round(config.check_ahead_m / cell_m)),
                max(1, round(config.lookahead_m / cell_m)),
                max(1, round(config.look_radius_m / cell_m)),
                config.max_bumps,
                config.robot_wait_limit,
                config.robot_wait_steps,
                config.bump_memory_steps,
            ],
            dtype=np.int64,
        )
        self._state = np.zeros((n, 6), dtype=np.int64)
        self._state[:, _LAST] = _STAY
        self._paths = np.zeros((n, 256, 2), dtype=np.int64)
        self._los = np.zeros((n, *scene.shape), dtype=bool)  # each robot's planning grid (its window)
        self._los_box = np.zeros((n, 4), dtype=np.int64)  # (y0, y1, x0, x1) of that window
        self._bumps = np.zeros(scene.shape, dtype=bool)
        self._bump_count = np.zeros(scene.shape, dtype=np.int32)  # live marks per cell
        self._bumps_at = np.zeros(scene.shape, dtype=np.int64)  # map version of the newest live mark
        self._bump_log = np.zeros((64 * _BUMP_SAMPLES * n, 3), dtype=np.int64)  # (expiry step, iy, ix)
        self._bump_ptr = np.zeros(2, dtype=np.int64)  # [oldest live entry, end] of the log
        self._need = np.zeros(n, dtype=np.int8)
        self._yield_cell = np.full((n, 2), -1, dtype=np.int64)  # where a robot giving way waits
        self._no_cells = np.zeros((0, 2), dtype=np.int64)
        robot = world.config.robot
        self._move_params = (
            scene.origin_xy[0],
            scene.origin_xy[1],
            cell_m,
            robot.forward_m,
            robot.turn_rad,
            (2 * radius) ** 2,
        )
        self._search_pause = 2 * config.robot_wait_limit  # steps without a new search after one found none
        self._bump_ahead = np.zeros(n, dtype=np.bool_)
        self._moves = np.zeros((n, _MAX_MOVES), dtype=np.int64)  # primitive-search plans, per robot
        self._moves_len = np.zeros(n, dtype=np.int64)  # 0: none
        self._moves_at = np.zeros(n, dtype=np.int64)  # next action of the plan
        self._moves_failed = np.full(n, -(10**9), dtype=np.int64)  # step of the last search that found none
        self._yield_steps = np.zeros(n, dtype=np.int64)  # steps since it began to give way

    # ------------------------------------------------------------------ public state
    @property
    def bumps(self) -> np.ndarray:
        """(H, W) bool: the collision map, cells a bump marked in the last ``bump_memory_steps`` steps."""
        return self._bumps

    def inflated_obstacles(self) -> np.ndarray:
        """(H, W) bool: the mapped obstacles inflated by the footprint, brought up to date now
        (:class:`~areasearch.geodesic.InflatedObstacles`); read-only for callers."""
        mapper = self.world.mapper
        assert mapper is not None
        return self._inflated.update(mapper.occupied)

    @property
    def paths(self) -> list[np.ndarray | None]:
        """Each robot's current path, (N, 2) cells from where it was planned to the goal, or None."""
        lengths = self._state[:, _LENGTH]
        return [self._paths[r, : lengths[r]].copy() if lengths[r] else None for r in range(len(self.goals))]

    @property
    def progress(self) -> np.ndarray:
        """(R,) index of the path cell nearest each robot."""
        return self._state[:, _PROGRESS].copy()

    def set_goals(
        self, goals: np.ndarray, tolerances_m: np.ndarray | None = None, routes: Routes | None = None
    ) -> None:
        """New long-term goals, (R, 2) cells; a row of -1 means "no goal" (the robot stays).

        ``tolerances_m`` (R,): how close counts as arrived, per robot (default ``goal_tolerance_m``;
        a target goal needs the robot within the cover radius of the target itself). ``routes``: the
        robots' distance fields of this decision (``Candidates.routes``, computed on the map as it is
        now), from which each robot's first path is read instead of re-planned."""
        goals = np.asarray(goals, dtype=np.int64).reshape(-1, 2)
        self.tolerances_m = (
            np.full(len(goals), self.config.goal_tolerance_m)
            if tolerances_m is None
            else np.asarray(tolerances_m, dtype=np.float64).reshape(-1)
        )
        for r in range(len(goals)):
            if not np.array_equal(goals[r], self.goals[r]):
                self._state[r, _LENGTH] = 0
                self._state[r, _PROGRESS] = 0
                self._state[r, _STUCK] = 0
                self._state[r, _WAITS] = 0
                self.unreachable[r] = False
                self.reached[r] = False
                self.settled[r] = False
                self.walled_in[r] = None
                self._yield_cell[r] = -1
                self._moves_len[r] = 0
                self._moves_failed[r] = -(10**9)
                if routes is not None and goals[r, 0] >= 0:
                    self._route(r, goals[r], routes)
        self.goals = goals.copy()

    def act(self, blocked_by: np.ndarray) -> np.ndarray:
        """(R,) actions for this step; ``blocked_by`` is the last step's ``StepResult.blocked_by``."""
        world = self.world
        mapper = world.mapper
        assert mapper is not None
        n = len(self.goals)
        if self._bump_ptr[1] + _BUMP_SAMPLES * n > len(self._bump_log):
            self._make_room_in_bump_log()
        actions = np.empty(n, dtype=np.int64)
        pending = _act_kernel(
            world.poses, blocked_by, self.goals, self.tolerances_m, self._paths, self._state,
            self.unreachable, self.reached, self.settled, mapper.explored, mapper.occupied, mapper.occupied_at,
            self._version() + 1, world.metrics.steps, self._bumps, self._bump_count, self._bumps_at,
            self._bump_log, self._bump_ptr, self._offsets, self._los, self._los_box, self._fparams,
            self._iparams, actions, self._need,
        )  # fmt: skip
        scene = world.scene
        assert scene is not None
        giving_way = np.flatnonzero(self._yield_cell[:, 0] >= 0)
        cells = scene.world_to_cell(world.poses[:, :2]) if pending or len(giving_way) else self._no_cells
        for r in giving_way:
            self._continue_giving_way(int(r), cells, actions)
        if pending:
            for r in np.flatnonzero(self._need):
                if self._yield_cell[r, 0] >= 0:
                    continue  # giving way: no re-plan towards the goal yet
                detour = self._need[r] == _DETOUR
                # a detour that did not help (still blocked 5 steps later): one of the two gives way
                stalled = detour and self._state[r, _WAITS] > self.config.robot_wait_steps + 5
                if (stalled and self._give_way(int(r), cells, blocked_by)) or self._replan(
                    int(r), cells, avoid_robots=detour
                ):
                    actions[r] = _drive(
                        int(r), world.poses, self._paths, self._state, self._los, self._los_box,
                        self._fparams, self._iparams,
                    )  # fmt: skip
                elif not detour:
                    self.unreachable[r] = True
        if self.config.primitive_search_m > 0:
            self._primitive_moves(actions, blocked_by)
        return actions

    # ------------------------------------------------------------------ primitive moves
    def _primitive_moves(self, actions: np.ndarray, blocked_by: np.ndarray) -> None:
        """Where the heading heuristic would drive a robot into a mapped obstacle (a narrow way in, a
        corner cut too close), plan the next moves with the primitives themselves
        (:func:`_primitive_search`) and follow that plan; a plan is dropped when a move of it is
        blocked (an unmapped obstacle, a team-mate), the goal changes, or it is done."""
        world = self.world
        mapper = world.mapper
        now = world.metrics.steps
        ox, oy, cell_m, forward_m, turn_rad, min_sep2 = self._move_params
        if not _bumps_ahead(
            mapper.occupied, self._clearance_cells, ox, oy, cell_m, world.poses, actions, forward_m,  # type: ignore[union-attr]
            self._moves_len, self._moves_failed, now - self._search_pause, self._bump_ahead,
        ):  # fmt: skip
            return  # no plan to follow, no FORWARD into a mapped obstacle: nothing to do (most steps)
        assert mapper is not None
        cfg = self.config
        poses = world.poses
        for r in range(len(self.goals)):
            if self.goals[r, 0] < 0 or self.unreachable[r] or self.reached[r] or self._yield_cell[r, 0] >= 0:
                self._moves_len[r] = 0
                continue
            if self._moves_len[r]:
                if blocked_by[r] != 0 or self._moves_at[r] >= self._moves_len[r]:
                    if blocked_by[r] == _OBSTACLE:
                        self._moves_failed[r] = now  # an obstacle the map does not show: no new search soon
                    self._moves_len[r] = 0
                else:
                    self._take(r, int(self._moves[r, self._moves_at[r]]), actions)
                    self._moves_at[r] += 1
                    continue
            if not self._bump_ahead[r]:
                continue
            others = np.delete(poses[:, :2], r, axis=0)
            gx, gy, tolerance = self._search_goal(r)
            m = math.ceil((cfg.primitive_search_m / 2 + forward_m + self._radius_m) / cell_m)
            here = np.floor((poses[r, 1::-1] - (oy, ox)) / cell_m).astype(np.int64)
            there = np.floor((np.array([gy, gx]) - (oy, ox)) / cell_m).astype(np.int64)
            h, w = mapper.shape
            y0, x0 = max(min(here[0], there[0]) - m, 0), max(min(here[1], there[1]) - m, 0)
            y1, x1 = min(max(here[0], there[0]) + m + 1, h), min(max(here[1], there[1]) + m + 1, w)
            length = _primitive_search(
                self._known_blocked(Box(y0, y1, x0, x1)), y0, x0, ox, oy, cell_m, poses[r], forward_m, turn_rad,
                others, min_sep2, gx, gy, tolerance, cfg.primitive_search_expansions,
                self._moves[r],
            )  # fmt: skip
            if length <= 0:
                self._moves_failed[r] = now
                continue
            self._moves_len[r] = length
            self._moves_at[r] = 1
            self._take(r, int(self._moves[r, 0]), actions)

    def _known_blocked(self, box: Box) -> np.ndarray:
        """Where a primitive plan may not put a robot centre in ``box``: within the clearance
        threshold of a mapped obstacle or of an unknown cell (a plan keeps to space the map shows
        free, so that the world lets every move of it pass)."""
        mapper = self.world.mapper
        assert mapper is not None
        h, w = mapper.shape
        pad = int(np.abs(self._offsets).max())
        big = Box(max(box.y0 - pad, 0), min(box.y1 + pad, h), max(box.x0 - pad, 0), min(box.x1 + pad, w))
        blocked = np.zeros(big.shape, dtype=bool)
        _inflate_kernel(~mapper.explored[big.slices] | mapper.occupied[big.slices], self._offsets, blocked)
        dy, dx = box.y0 - big.y0, box.x0 - big.x0
        return blocked[dy : dy + box.shape[0], dx : dx + box.shape[1]]

    def _search_goal(self, r: int) -> tuple[float, float, float]:
        """Where a primitive search for robot ``r`` aims: its goal (within its arrival tolerance) if
        the goal is within ``primitive_search_m``, else the farthest cell of its path ahead within that
        distance (within half a forward step)."""
        fp = self._fparams
        ox, oy, cell_m = fp[_F_OX], fp[_F_OY], fp[_F_CELL]
        pose = self.world.poses[r]
        reach = self.config.primitive_search_m
        goal = self.goals[r]
        gx, gy = ox + (goal[1] + 0.5) * cell_m, oy + (goal[0] + 0.5) * cell_m
        length = int(self._state[r, _LENGTH])
        if math.hypot(gx - pose[0], gy - pose[1]) <= reach or length == 0:
            return gx, gy, float(self.tolerances_m[r])
        ahead = self._paths[r, int(self._state[r, _PROGRESS]) : length]
        xy = np.stack([ox + (ahead[:, 1] + 0.5) * cell_m, oy + (ahead[:, 0] + 0.5) * cell_m], axis=1)
        within = np.flatnonzero(np.hypot(*(xy - pose[:2]).T) <= reach)
        k = int(within[-1]) if len(within) else 0
        return float(xy[k, 0]), float(xy[k, 1]), self.world.config.robot.forward_m / 2

    def _take(self, r: int, action: int, actions: np.ndarray) -> None:
        actions[r] = action
        self._state[r, _LAST] = action
        self._need[r] = 0

    # ------------------------------------------------------------------ giving way
    def _blocker(self, r: int) -> int:
        """The team-mate whose footprint a FORWARD of robot ``r`` would overlap (the nearest one), or -1."""
        poses = self.world.poses
        step = self.world.config.robot.forward_m
        ahead = poses[r, :2] + step * np.array([math.cos(poses[r, 2]), math.sin(poses[r, 2])])
        d = np.hypot(*(poses[:, :2] - ahead).T)
        d[r] = np.inf
        o = int(np.argmin(d))
        return o if d[o] < 2 * self._radius_m + 1e-9 else -1

    def _give_way(self, r: int, cells: np.ndarray, blocked_by: np.ndarray) -> bool:
        """Robot ``r`` is blocked by a team-mate and finds no way round it. If the team-mate has no goal,
        it moves to the nearest cell off ``r``'s way; if both block each other, the one of higher
        index moves off the other's way (its path ahead and its footprint), waits there while the
        other passes, then goes on to its goal. True if robot ``r`` itself now has a path to drive."""
        o = self._blocker(r)
        if o < 0:
            return False
        if self.goals[o, 0] < 0:
            spot = self._spot_off_the_way(o, r, cells)
            if spot is None:
                return False
            # the idle robot drives to its spot as to a goal (arrives, stays) until its next goal
            self.goals[o] = spot
            self.tolerances_m[o] = self._cell_m
            self.unreachable[o] = self.reached[o] = self.settled[o] = False
            self._state[o, _STUCK] = self._state[o, _WAITS] = 0
            return False
        if r < o or blocked_by[o] != _ROBOT:
            return False
        spot = self._spot_off_the_way(r, o, cells)
        if spot is None:
            return False
        self._yield_cell[r] = spot
        self._yield_steps[r] = 0
        return True

    def _spot_off_the_way(self, mover: int, passer: int, cells: np.ndarray) -> np.ndarray | None:
        """Plan ``mover``'s path to the nearest cell (within twice ``local_margin_m``) off ``passer``'s
        way: clear of its footprint and of the footprints along its path ahead. Stores the path as
        ``mover``'s; returns the cell, or None if there is none."""
        mapper = self.world.mapper
        assert mapper is not None
        h, w = mapper.shape
        m = 2 * self._local_margin
        here = cells[mover]
        box = Box(max(here[0] - m, 0), min(here[0] + m + 1, h), max(here[1] - m, 0), min(here[1] + m + 1, w))
        passable = self._grid(box, cells)
        _block_robots(passable, box.y0, box.x0, cells, mover, self._robot_offsets)
        keep_off = np.zeros_like(passable)
        # the passer's next move (a footprint and a step round it) and the footprints along its path ahead
        reach = disc_offsets((2 * self._radius_m + self.world.config.robot.forward_m) / self._cell_m)
        way = [(cells[passer][None], reach)]
        length, progress = int(self._state[passer, _LENGTH]), int(self._state[passer, _PROGRESS])
        if length:
            way.append((self._paths[passer, progress : min(length, progress + 2 * m)], self._robot_offsets))
        for points, disc in way:
            for y, x in points:
                ys, xs = y + disc[:, 0] - box.y0, x + disc[:, 1] - box.x0
                inside = (ys >= 0) & (ys < passable.shape[0]) & (xs >= 0) & (xs < passable.shape[1])
                keep_off[ys[inside], xs[inside]] = True
        field = distance_field(passable, here - box.origin, self._cell_m)
        spots = np.isfinite(field) & ~keep_off
        if not spots.any():
            return None
        y, x = np.unravel_index(int(np.argmin(np.where(spots, field, np.inf))), field.shape)
        back = _descend(field, int(y), int(x), field.size)
        if len(back) == 0:
            return None
        self._store(mover, back[::-1] + box.origin, box, passable, self._version() + 1)
        return np.array([int(y) + box.y0, int(x) + box.x0])

    def _continue_giving_way(self, r: int, cells: np.ndarray, actions: np.ndarray) -> None:
        """Robot ``r`` gives way: it drives to its spot (the kernel follows the stored path), stays
        there ``robot_wait_limit`` steps, then re-plans to its goal."""
        self._yield_steps[r] += 1
        arrived = np.abs(cells[r] - self._yield_cell[r]).max() <= 1
        if arrived or self._need[r] != 0:
            actions[r] = _STAY
            self._state[r, _LAST] = _STAY
            self._need[r] = 0
        if self._yield_steps[r] > 2 * self.config.robot_wait_limit or self.goals[r, 0] < 0:
            self._yield_cell[r] = -1
            self._state[r, _LENGTH] = 0  # re-plan to the goal on the next step
            self._state[r, _WAITS] = 0

    # ------------------------------------------------------------------ internals
    def _version(self) -> int:
        """Map version of the current map: twice the mapper's integrations (obstacles it marks carry
        ``2 * occupied_at``); bump marks of a step carry one more, paths planned carry the version
        of the map they were planned on (decision routes: before this step's bumps, re-plans: after)."""
        mapper = self.world.mapper
        assert mapper is not None
        return 2 * mapper.integrations

    def _make_room_in_bump_log(self) -> None:
        head, tail = (int(v) for v in self._bump_ptr)
        live = self._bump_log[head:tail].copy()
        size = len(self._bump_log)
        while len(live) + _BUMP_SAMPLES * len(self.goals) > size // 2:
            size *= 2
        if size != len(self._bump_log):
            self._bump_log = np.zeros((size, 3), dtype=np.int64)
        self._bump_log[: len(live)] = live
        self._bump_ptr[:] = (0, len(live))

    def _store(self, r: int, path: np.ndarray, box: Box, passable: np.ndarray, version: int) -> None:
        """Make ``path`` (global cells) robot ``r``'s path, planned on ``passable`` (the grid of ``box``)."""
        if len(path) > self._paths.shape[1]:
            grown = np.zeros((len(self.goals), max(len(path), 2 * self._paths.shape[1]), 2), dtype=np.int64)
            grown[:, : self._paths.shape[1]] = self._paths
            self._paths = grown
        self._paths[r, : len(path)] = path
        self._state[r, _LENGTH] = len(path)
        self._state[r, _PROGRESS] = 0
        self._state[r, _PLANNED] = version
        self._los[r, box.y0 : box.y1, box.x0 : box.x1] = passable
        self._los_box[r] = (box.y0, box.y1, box.x0, box.x1)

    def _route(self, r: int, goal: np.ndarray, routes: Routes) -> None:
        """Robot ``r``'s path to ``goal`` read off its decision-time distance field (goal -> robot
        by steepest descent, reversed); left to :meth:`act` to plan if the goal is outside the window."""
        box = routes.box
        local = goal - box.origin
        if not (0 <= local[0] < box.shape[0] and 0 <= local[1] < box.shape[1]):
            return
        field = routes.fields[r]
        back = _descend(field, int(local[0]), int(local[1]), field.size)
        if len(back) == 0:
            self.unreachable[r] = True
            return
        self._store(r, back[::-1] + box.origin, box, routes.passable, self._version())

    def _grid(self, box: Box, cells: np.ndarray) -> np.ndarray:
        """The planning grid of ``box`` now: known obstacles inflated, unknown cells passable near
        frontiers, the collision map blocked, the robots' cells free."""
        mapper = self.world.mapper
        assert mapper is not None
        passable, _ = window_grid(
            mapper.explored,
            mapper.occupied,
            box,
            self._cell_m,
            self._radius_m,
            unknown_margin_m=self.config.unknown_margin_m,
            keep_free=cells,
            impassable=self._bumps if self._bump_ptr[1] > self._bump_ptr[0] else None,
            inflated=self._inflated.update(mapper.occupied),
        )
        return passable

    def _replan(self, r: int, cells: np.ndarray, avoid_robots: bool) -> bool:
        """FMM path for robot ``r``: first in a window around the robot and its goal grown by
        ``local_margin_m`` (cheap), then, if that finds none, over the whole planning window. A
        detour round team-mates (``avoid_robots``) is sought in the local window only.

        A connectivity check comes first (:func:`_connected`), so a goal that cannot be reached
        costs no FMM; a robot found walled in (by obstacles and bump marks) is recorded in
        :attr:`walled_in`, so that its caller can pick a goal it can reach."""
        self.replans += 1
        mapper = self.world.mapper
        assert mapper is not None
        goal, here = self.goals[r], cells[r]
        m = self._local_margin
        h, w = mapper.shape
        self.walled_in[r] = None
        if not avoid_robots and not (abs(goal[0] - here[0]) <= m and abs(goal[1] - here[1]) <= m):
            # a goal far away: first make sure the robot is not walled in (by bump marks, mostly),
            # which a small window round the robot shows at a fraction of the cost of the others
            near = Box(max(here[0] - m, 0), min(here[0] + m + 1, h), max(here[1] - m, 0), min(here[1] + m + 1, w))
            passable = self._grid(near, cells)
            side = np.empty(passable.size, dtype=np.uint8)
            if _enclosed(passable, here[0] - near.y0, here[1] - near.x0, side):
                self.walled_in[r] = (near, side.reshape(passable.shape) == 1)
                return False
        box = Box(
            max(min(here[0], goal[0]) - m, 0),
            min(max(here[0], goal[0]) + m + 1, h),
            max(min(here[1], goal[1]) - m, 0),
            min(max(here[1], goal[1]) + m + 1, w),
        )
        while True:
            passable = self._grid(box, cells)
            if avoid_robots:
                _block_robots(passable, box.y0, box.x0, cells, r, self._robot_offsets)
            side = np.empty(passable.size, dtype=np.uint8)
            path, verdict = _plan_kernel(
                passable, here[0] - box.y0, here[1] - box.x0, goal[0] - box.y0, goal[1] - box.x0, side
            )
            if verdict == _CONNECTED:
                self._store(r, path + box.origin, box, passable, self._version() + 1)
                return True
            if verdict == _START_CLOSED and not avoid_robots:
                self.walled_in[r] = (box, side.reshape(passable.shape) == 1)
            if verdict != _NOT_HERE or avoid_robots:
                return False  # walled in, the goal walled in, or no detour nearby
            goals = self.goals[self.goals[:, 0] >= 0]
            whole = region_box(mapper.explored, self._window_margin, np.concatenate([cells, goals]))
            if whole == box:
                return False
            box = whole
