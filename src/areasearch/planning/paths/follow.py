"""Following a path: how a robot gets from where it is to its long-term goal.

:class:`Follower` holds the robots' paths and their progress along them, and plans them:

* planning: at a decision the path is read off the robot's decision-time distance field
  (:meth:`Follower.route`); a re-plan plans by FMM (:mod:`~areasearch.planning.paths.planning`), first in a
  window round the robot and its goal, then over the whole planning window (:meth:`Follower.replan`);
  a detour round team-mates plans on a grid with their footprints blocked;
* following: the step kernel (:func:`act_kernel`) of every robot: arrival and the look round at the
  goal, the waits behind a team-mate and the detour requests (every ``detour_every_steps`` blocked
  tries), the robot's progress (the nearest path cell within ``progress_window_cells`` ahead), the
  check of the path ahead for newly mapped obstacles and bump marks (``check_ahead_m``), the
  line-of-sight short-term goal (``lookahead_m``) and the heading heuristic (:func:`heading_action`)
  that turns it into an action; :func:`drive` is the same for a path just planned.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ...sim.world import Action
from ..candidates import Routes
from ..grid import Box, region_box
from ..window import window_grid
from .bumps import BumpMemory, expire_bumps, mark_bumps
from .context import Goals, PlannerContext
from .planning import CONNECTED, NOT_HERE, START_CLOSED, block_robots, enclosed, plan_kernel, route_path
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
    map_of: np.ndarray,
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
    (:func:`~areasearch.planning.paths.bumps.expire_bumps`, :func:`~areasearch.planning.paths.bumps.mark_bumps`), then
    per robot arrival, waits and the path ahead; returns how many robots need a
    re-plan or a detour from Python (``need``), their ``actions`` being STAY until then.

    ``explored``, ``occupied``, ``occupied_at`` are (M, H, W) stacks of maps, robot ``r`` reading map
    ``map_of[r]`` (one map for the team, or each robot's own under limited communication). ``version`` is
    the map version of this step (bumps marked now are newer than paths planned before this step, not
    newer than re-plans of this step), ``now`` the world's step count."""
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
                    fy, fx = _nearest_frontier(
                        explored[map_of[r]], occupied[map_of[r]], goals[r, 0], goals[r, 1], iparams[I_LOOK], hy, hx
                    )
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
                        if not _newly_blocked(
                            paths, r, best, stop, state[r, PLANNED], occupied_at[map_of[r]], bumps_at, offsets
                        ):
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


def heading_action(pose: np.ndarray, waypoint_xy: tuple[float, float] | np.ndarray, tolerance_rad: float) -> int:
    """FORWARD if the waypoint lies within ``tolerance_rad`` of the heading, else turn towards it."""
    bearing = math.atan2(waypoint_xy[1] - pose[1], waypoint_xy[0] - pose[0])
    error = (bearing - pose[2] + math.pi) % (2 * math.pi) - math.pi
    if abs(error) <= tolerance_rad:
        return int(Action.FORWARD)
    return int(Action.TURN_LEFT if error > 0 else Action.TURN_RIGHT)


# ---------------------------------------------------------------------------------- the follower


class Follower:
    """The robots' paths and how far each has followed its own: the (R, 6) state of
    :mod:`~areasearch.planning.paths.state` (``PROGRESS`` ... ``LAST``), the path buffer, each path's planning
    grid (its line-of-sight window), what the step kernel left to Python, and the re-plans.
    Reads the goals and the collision map; changes neither but for the goals it finds unreachable."""

    def __init__(self, context: PlannerContext, goals: Goals, bumps: BumpMemory) -> None:
        scene = context.world.scene
        assert scene is not None
        n = context.num_robots
        self._context, self._goals, self._bumps = context, goals, bumps
        self._state = np.zeros((n, 6), dtype=np.int64)
        self._state[:, LAST] = STAY
        self._paths = np.zeros((n, context.config.path_buffer_cells, 2), dtype=np.int64)  # grows for longer paths
        self._los = np.zeros((n, *scene.shape), dtype=bool)  # each robot's planning grid (its window)
        self._los_box = np.zeros((n, 4), dtype=np.int64)  # (y0, y1, x0, x1) of that window
        self._need = np.zeros(n, dtype=np.int8)  # REPLAN / DETOUR: what the step kernel left to Python
        self.walled_in: list[tuple[Box, np.ndarray] | None] = [None] * n
        """Per robot, after a re-plan that found it walled in (obstacles and bump marks all round):
        the window and the (h, w) mask of the cells it can still reach; else None."""
        self.replans = 0

    # ------------------------------------------------------------------ what the other parts read
    @property
    def waits(self) -> np.ndarray:
        """(R,) view of the robots' blocked tries without moving (the jam tracker caps them in place)."""
        return self._state[:, WAITS]

    @property
    def buffer_cells(self) -> int:
        """Cells the path buffer holds per robot."""
        return int(self._paths.shape[1])

    def paths(self) -> list[np.ndarray | None]:
        """Each robot's current path, (N, 2) cells from where it was planned to the goal, or None."""
        lengths = self._state[:, LENGTH]
        return [self._paths[r, : lengths[r]].copy() if lengths[r] else None for r in range(len(lengths))]

    def progress(self) -> np.ndarray:
        """(R,) index of the path cell nearest each robot."""
        return self._state[:, PROGRESS].copy()

    def has_path(self, r: int) -> bool:
        return bool(self._state[r, LENGTH])

    def cells_left(self, r: int) -> int:
        """Path cells from the one nearest robot ``r`` to its goal."""
        return int(self._state[r, LENGTH] - self._state[r, PROGRESS])

    def path_ahead(self, r: int, cells: int | None = None) -> np.ndarray:
        """(N, 2) robot ``r``'s path from the cell nearest it, ``cells`` cells of it (default: to the end)."""
        length, progress = int(self._state[r, LENGTH]), int(self._state[r, PROGRESS])
        return self._paths[r, progress : length if cells is None else min(length, progress + cells)]

    def needs(self, r: int) -> bool:
        """The step kernel left robot ``r`` to Python (a re-plan or a detour)."""
        return bool(self._need[r] != 0)

    # ------------------------------------------------------------------ what the other parts change
    def forget(self, r: int) -> None:
        """A new goal for robot ``r``: no path, no progress, no bumps or blocked tries, not walled in."""
        self.walled_in[r] = None
        self._state[r, LENGTH] = 0
        self._state[r, PROGRESS] = 0
        self._state[r, STUCK] = 0
        self._state[r, WAITS] = 0

    def reset_tries(self, r: int) -> None:
        """Robot ``r``'s bumps and blocked tries start again from zero."""
        self._state[r, STUCK] = self._state[r, WAITS] = 0

    def drop_path(self, r: int) -> None:
        """Robot ``r`` re-plans to its goal on the next step, its blocked tries from zero."""
        self._state[r, LENGTH] = 0
        self._state[r, WAITS] = 0

    def take(self, r: int, action: int, actions: np.ndarray) -> None:
        """Robot ``r`` takes ``action`` this step instead of what the step kernel chose (no re-plan)."""
        actions[r] = action
        self._state[r, LAST] = action
        self._need[r] = 0

    # ------------------------------------------------------------------ the step
    def step(self, blocked_by: np.ndarray, tolerances: np.ndarray, actions: np.ndarray) -> int:
        """The step kernel (:func:`act_kernel`) for every robot: ``actions`` filled, the collision map
        brought up to date; returns how many robots need Python (:meth:`pending`)."""
        context, goals, memory = self._context, self._goals, self._bumps
        world = context.world
        explored, occupied, occupied_at, map_of = context.map_stacks()
        pending: int = act_kernel(
            world.believed_poses, blocked_by, goals.cells, tolerances, self._paths, self._state,
            goals.unreachable, goals.reached, goals.settled, explored, occupied, occupied_at, map_of,
            context.version() + 1, world.metrics.steps, memory.mask, memory.count, memory.at,
            memory.log, memory.ptr, context.offsets, self._los, self._los_box, context.fparams,
            context.iparams, actions, self._need,
        )  # fmt: skip
        return pending

    def pending(self) -> list[tuple[int, bool]]:
        """The robots the step kernel left to Python, each with whether it asked for a detour."""
        return [(int(r), bool(self._need[r] == DETOUR)) for r in np.flatnonzero(self._need)]

    def drive(self, r: int) -> int:
        """The action of robot ``r`` on the path it has just planned (:func:`drive`)."""
        action: int = drive(
            r, self._context.world.believed_poses, self._paths, self._state, self._los, self._los_box,
            self._context.fparams, self._context.iparams,
        )  # fmt: skip
        return action

    # ------------------------------------------------------------------ planning (Python)
    def store_path(self, r: int, path: np.ndarray, box: Box, passable: np.ndarray, version: int) -> None:
        """Make ``path`` (global cells) robot ``r``'s path, planned on ``passable`` (the grid of ``box``)
        at map version ``version``; the path buffer doubles when the path does not fit."""
        if len(path) > self._paths.shape[1]:
            grown = np.zeros((len(self._paths), max(len(path), 2 * self._paths.shape[1]), 2), dtype=np.int64)
            grown[:, : self._paths.shape[1]] = self._paths
            self._paths = grown
        self._paths[r, : len(path)] = path
        self._state[r, LENGTH] = len(path)
        self._state[r, PROGRESS] = 0
        self._state[r, PLANNED] = version
        self._los[r, box.y0 : box.y1, box.x0 : box.x1] = passable
        self._los_box[r] = (box.y0, box.y1, box.x0, box.x1)

    def planning_grid(self, box: Box, cells: np.ndarray, robot: int | None = None) -> np.ndarray:
        """The planning grid of ``box`` now: known obstacles inflated, unknown cells passable near
        frontiers, the collision map blocked, the robots' cells free; on ``robot``'s map
        (:meth:`~areasearch.planning.paths.context.PlannerContext.map_of`; None: the team's)."""
        context, memory = self._context, self._bumps
        mapper = context.map_of(robot)
        passable, _ = window_grid(
            mapper.explored,
            mapper.occupied,
            box,
            context.cell_m,
            context.radius_m,
            unknown_margin_m=context.config.unknown_margin_m,
            keep_free=cells,
            impassable=memory.mask if memory.live else None,
            inflated=context.inflated_obstacles(robot),
        )
        return passable

    def route(self, r: int, goal: np.ndarray, routes: Routes) -> None:
        """Robot ``r``'s path to ``goal`` read off its decision-time distance field (goal -> robot
        by steepest descent, reversed); left to the step to plan if the goal is outside the window."""
        box = routes.box
        local = goal - box.origin
        if not (0 <= local[0] < box.shape[0] and 0 <= local[1] < box.shape[1]):
            return
        path = route_path(routes, r, local)
        if len(path) == 0:
            self._goals.unreachable[r] = True
            return
        self.store_path(r, path + box.origin, box, routes.passable, self._context.version())

    def replan(self, r: int, cells: np.ndarray, avoid_robots: bool) -> bool:
        """FMM path for robot ``r``: first in a window around the robot and its goal grown by
        ``local_margin_m`` (cheap), then, if that finds none, over the whole planning window. A
        detour round team-mates (``avoid_robots``) is sought in the local window only.

        A connectivity check comes first (:func:`~areasearch.planning.paths.planning.connected`), so a goal
        that cannot be reached costs no FMM; a robot found walled in (by obstacles and bump marks) is
        recorded in :attr:`walled_in`, so that its caller can pick a goal it can reach."""
        self.replans += 1
        context = self._context
        mapper = context.map_of(r)
        goal, here = self._goals.cells[r], cells[r]
        m = context.local_margin
        h, w = mapper.shape
        self.walled_in[r] = None
        if not avoid_robots and not (abs(goal[0] - here[0]) <= m and abs(goal[1] - here[1]) <= m):
            # a goal far away: first make sure the robot is not walled in (by bump marks, mostly),
            # which a small window round the robot shows at a fraction of the cost of the others
            near = Box(max(here[0] - m, 0), min(here[0] + m + 1, h), max(here[1] - m, 0), min(here[1] + m + 1, w))
            passable = self.planning_grid(near, cells, r)
            side = np.empty(passable.size, dtype=np.uint8)
            if enclosed(passable, here[0] - near.y0, here[1] - near.x0, side):
                self.walled_in[r] = (near, side.reshape(passable.shape) == 1)
                return False
        box = Box(
            max(min(here[0], goal[0]) - m, 0),
            min(max(here[0], goal[0]) + m + 1, h),
            max(min(here[1], goal[1]) - m, 0),
            min(max(here[1], goal[1]) + m + 1, w),
        )
        while True:
            passable = self.planning_grid(box, cells, r)
            if avoid_robots:
                block_robots(passable, box.y0, box.x0, cells, r, context.robot_offsets)
            side = np.empty(passable.size, dtype=np.uint8)
            path, verdict = plan_kernel(
                passable, here[0] - box.y0, here[1] - box.x0, goal[0] - box.y0, goal[1] - box.x0, side
            )
            if verdict == CONNECTED:
                self.store_path(r, path + box.origin, box, passable, context.version() + 1)
                return True
            if verdict == START_CLOSED and not avoid_robots:
                self.walled_in[r] = (box, side.reshape(passable.shape) == 1)
            if verdict != NOT_HERE or avoid_robots:
                return False  # walled in, the goal walled in, or no detour nearby
            goals = self._goals.cells[self._goals.cells[:, 0] >= 0]
            whole = region_box(mapper.explored, context.window_margin, np.concatenate([cells, goals]))
            if whole == box:
                return False
            box = whole
