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
* **re-planning**: a robot re-plans after it bumps into something and when the mapper marks a new
  obstacle within a footprint of the next ``check_ahead_m`` of its path, by FMM from the goal that
  stops once it reaches the robot, first in a window around the robot and its goal;
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
  as in Chaplot et al. 2020) for ``bump_memory_steps`` steps, and it re-plans; after
  ``max_bumps`` such bumps without moving the goal counts as unreachable;
* **unreachable**: when no path exists the robot stays and :attr:`ActionPlanner.unreachable` says so;
  the caller (the high-level environment) then gives it another goal.

Paths are (N, 2) cell arrays from the robot's cell to the goal cell; distances in metres.
"""

from __future__ import annotations

import math
from collections import deque

import numba
import numpy as np

from .candidates import Routes, planning_window
from .config import PathConfig
from .geodesic import Box, clearance_threshold_m, disc_offsets, distance_field, region_box
from .world import BLOCKED_BY_OBSTACLE, BLOCKED_BY_ROBOT, Action, World


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
def _blocked(
    occupied: np.ndarray, bumps: np.ndarray, path: np.ndarray, start: int, stop: int, offsets: np.ndarray
) -> bool:
    """True if an occupied cell lies within the footprint disc (``offsets``) of a cell of
    path[start:stop], or the path crosses a bumped cell."""
    h, w = occupied.shape
    for i in range(start, min(stop, path.shape[0])):
        y, x = path[i, 0], path[i, 1]
        if bumps[y, x]:
            return True
        for k in range(offsets.shape[0]):
            ny, nx = y + offsets[k, 0], x + offsets[k, 1]
            if 0 <= ny < h and 0 <= nx < w and occupied[ny, nx]:
                return True
    return False


@numba.njit(cache=True, nogil=True)
def _line_clear(passable: np.ndarray, y0: int, x0: int, y1: int, x1: int) -> bool:
    """True if every cell on the straight line between two cells (supercover sampling) is passable."""
    n = max(abs(y1 - y0), abs(x1 - x0)) * 2
    for k in range(1, n + 1):
        y = int(math.floor(y0 + 0.5 + (y1 - y0) * k / n))
        x = int(math.floor(x0 + 0.5 + (x1 - x0) * k / n))
        if y < 0 or x < 0 or y >= passable.shape[0] or x >= passable.shape[1] or not passable[y, x]:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _short_term_goal(passable: np.ndarray, path: np.ndarray, here: np.ndarray, i: int, lookahead: int) -> int:
    """Index of the short-term goal: the farthest path cell at most ``lookahead`` cells ahead of
    ``i`` that the robot sees in a straight passable line (so it never cuts a corner), at least i+1."""
    last = path.shape[0] - 1
    for j in range(min(i + lookahead, last), i + 1, -1):
        if _line_clear(passable, here[0], here[1], path[j, 0], path[j, 1]):
            return j
    return min(i + 1, last)


@numba.njit(cache=True, nogil=True)
def _follow(
    path: np.ndarray,
    progress: int,
    here: np.ndarray,
    occupied: np.ndarray,
    bumps: np.ndarray,
    offsets: np.ndarray,
    check: int,
    grid: np.ndarray,
    grid_origin: np.ndarray,
    lookahead: int,
) -> tuple[int, int]:
    """One step of path following: the new progress (index of the path cell nearest the robot,
    searched a little ahead of the last) and the short-term goal index, or -1 if the next ``check``
    cells of the path are now blocked (re-plan)."""
    best, best_d = progress, np.inf
    for k in range(progress, min(path.shape[0], progress + 40)):
        d = (path[k, 0] - here[0]) ** 2 + (path[k, 1] - here[1]) ** 2
        if d < best_d:
            best, best_d = k, d
    if _blocked(occupied, bumps, path, best, best + check, offsets):
        return best, -1
    local = path - grid_origin
    return best, _short_term_goal(grid, local, here - grid_origin, best, lookahead)


@numba.njit(cache=True, nogil=True)
def _nearest_frontier(
    explored: np.ndarray, occupied: np.ndarray, centre: np.ndarray, k: int, here: np.ndarray
) -> tuple[int, int]:
    """The frontier cell (explored, free, with an unknown 4-neighbour) within ``k`` cells (Chebyshev)
    of ``centre`` that is nearest to ``here``; (-1, -1) if there is none."""
    h, w = explored.shape
    best_y, best_x, best_d = -1, -1, np.inf
    for y in range(max(centre[0] - k, 0), min(centre[0] + k + 1, h)):
        for x in range(max(centre[1] - k, 0), min(centre[1] + k + 1, w)):
            if not explored[y, x] or occupied[y, x]:
                continue
            if (
                (y > 0 and not explored[y - 1, x])
                or (y < h - 1 and not explored[y + 1, x])
                or (x > 0 and not explored[y, x - 1])
                or (x < w - 1 and not explored[y, x + 1])
            ):
                d = (y - here[0]) ** 2 + (x - here[1]) ** 2
                if d < best_d:
                    best_y, best_x, best_d = y, x, d
    return best_y, best_x


def plan_path(passable: np.ndarray, start: np.ndarray, goal: np.ndarray, cell_m: float) -> np.ndarray:
    """FMM shortest path (N, 2) cells from ``start`` to ``goal`` over ``passable``; empty if none.

    The distance field is computed from the goal and stops once the start is settled.
    """
    start = np.asarray(start, dtype=np.int64)
    goal = np.asarray(goal, dtype=np.int64)
    grid = passable.copy()
    grid[start[0], start[1]] = True
    field = distance_field(grid, goal, cell_m, stop_at=start[None])
    return _descend(field / cell_m, int(start[0]), int(start[1]), grid.size)


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
        self.paths: list[np.ndarray | None] = [None] * n
        self.progress = np.zeros(n, dtype=np.int64)
        self.unreachable = np.zeros(n, dtype=bool)
        self.reached = np.zeros(n, dtype=bool)
        self.settled = np.zeros(n, dtype=bool)
        """Arrived and looked at what there was to see around the goal."""
        self.replans = 0
        scene = world.scene
        assert scene is not None
        self._cell_m = scene.cell_m
        radius = world.config.robot.radius_m
        self._radius_m = radius
        self._clear_cells = clearance_threshold_m(scene.cell_m, radius) / scene.cell_m
        self._offsets = disc_offsets(self._clear_cells)
        self._lookahead = max(1, round(config.lookahead_m / scene.cell_m))
        self._check = max(1, round(config.check_ahead_m / scene.cell_m))
        self._tolerance = world.config.robot.turn_rad / 2 + 1e-6
        self._bumps = np.zeros(scene.shape, dtype=bool)
        self._bump_log: deque[tuple[int, int, int]] = deque()  # (expiry step, iy, ix), oldest first
        self._stuck = np.zeros(n, dtype=np.int64)
        self._waits = np.zeros(n, dtype=np.int64)
        self._last = np.full(n, int(Action.STAY), dtype=np.int64)
        self._look_cells = max(1, round(config.look_radius_m / scene.cell_m))
        self._view_half = math.radians(world.config.camera.hfov_deg) / 4
        self._window_cache: tuple[Box, np.ndarray] | None = None
        self._window_key: tuple[int, Box | None] | None = None
        self._grids: list[tuple[Box, np.ndarray]] = [(Box(0, 0, 0, 0), np.zeros((0, 0), dtype=bool))] * n

    def set_goals(
        self, goals: np.ndarray, tolerances_m: np.ndarray | None = None, routes: Routes | None = None
    ) -> None:
        """New long-term goals, (R, 2) cells; a row of -1 means "no goal" (the robot stays).

        ``tolerances_m`` (R,): how close counts as arrived, per robot (default ``goal_tolerance_m``;
        a target goal needs the robot within the cover radius of the target itself). ``routes``: the
        robots' distance fields of this decision (``Candidates.routes``), from which each robot's
        first path is read instead of re-planned."""
        goals = np.asarray(goals, dtype=np.int64).reshape(-1, 2)
        self.tolerances_m = (
            np.full(len(goals), self.config.goal_tolerance_m)
            if tolerances_m is None
            else np.asarray(tolerances_m, dtype=np.float64).reshape(-1)
        )
        for r in range(len(goals)):
            if not np.array_equal(goals[r], self.goals[r]):
                self.paths[r] = None
                self.unreachable[r] = False
                self.reached[r] = False
                self.settled[r] = False
                self._stuck[r] = 0
                self._waits[r] = 0
                if routes is not None and goals[r, 0] >= 0:
                    self._route(r, goals[r], routes)
        self.goals = goals.copy()

    def _route(self, r: int, goal: np.ndarray, routes: Routes) -> None:
        """Robot ``r``'s path to ``goal`` read off its decision-time distance field (goal -> robot
        by steepest descent, reversed); left to :meth:`act` to plan if the goal is outside the window."""
        box = routes.box
        local = goal - box.origin
        if not (0 <= local[0] < box.shape[0] and 0 <= local[1] < box.shape[1]):
            return
        field = routes.fields[r]
        back = _descend(field / self._cell_m, int(local[0]), int(local[1]), field.size)
        if len(back) == 0:
            self.unreachable[r] = True
            return
        self.paths[r] = back[::-1] + box.origin
        self.progress[r] = 0
        self._grids[r] = (box, routes.passable)

    def act(self, blocked_by: np.ndarray) -> np.ndarray:
        """(R,) actions for this step; ``blocked_by`` is the last step's ``StepResult.blocked_by``."""
        world = self.world
        mapper, scene = world.mapper, world.scene
        assert mapper is not None and scene is not None
        n = len(self.goals)
        actions = np.full(n, int(Action.STAY), dtype=np.int64)
        poses = world.poses
        ox, oy, cell_m = scene.origin_xy[0], scene.origin_xy[1], scene.cell_m
        cells = scene.world_to_cell(poses[:, :2])
        self._forget_bumps()
        for r in range(n):
            if blocked_by[r] == BLOCKED_BY_OBSTACLE:
                self._bump(r)
            goal = self.goals[r]
            if goal[0] < 0 or self.unreachable[r]:
                continue
            gx, gy = ox + (goal[1] + 0.5) * cell_m, oy + (goal[0] + 0.5) * cell_m
            if math.hypot(gx - poses[r, 0], gy - poses[r, 1]) <= self.tolerances_m[r]:
                self.reached[r] = True
                actions[r] = self._look_around(r, goal)
                continue
            moved = self._last[r] == Action.FORWARD and not blocked_by[r]
            bumped = blocked_by[r] == BLOCKED_BY_OBSTACLE
            self._stuck[r] = 0 if moved else self._stuck[r] + int(bumped)
            if moved:
                self._waits[r] = 0
            elif blocked_by[r] == BLOCKED_BY_ROBOT:
                self._waits[r] += 1
            if self._stuck[r] > self.config.max_bumps or self._waits[r] > self.config.robot_wait_limit:
                self.unreachable[r] = True
                continue
            if blocked_by[r] == BLOCKED_BY_ROBOT and self._waits[r] <= self.config.robot_wait_steps:
                continue  # give the other robot a moment to pass (STAY)
            path = self.paths[r]
            target = -1
            if blocked_by[r] == BLOCKED_BY_ROBOT and (self._waits[r] - self.config.robot_wait_steps) % 5 == 1:
                # go round the team-mates if there is a way (tried every 5th blocked try); else wait
                detour = self._replan(r, cells, avoid_robots=True)
                if detour is None:
                    continue
                path = self.paths[r] = detour
                self.progress[r] = 0
            if path is not None and not bumped:
                box, grid = self._grids[r]  # the grid the path was planned on
                progress, target = _follow(
                    path, int(self.progress[r]), cells[r], mapper.occupied, self._bumps, self._offsets,
                    self._check, grid, box.origin, self._lookahead,
                )  # fmt: skip
                self.progress[r] = progress
            if target < 0:
                path = self._replan(r, cells, avoid_robots=False)
                self.paths[r] = path
                self.progress[r] = 0
                if path is None:
                    self.unreachable[r] = True
                    continue
                box, grid = self._grids[r]
                _, target = _follow(
                    path, 0, cells[r], mapper.occupied, self._bumps, self._offsets, 0, grid, box.origin,
                    self._lookahead,
                )  # fmt: skip
            assert path is not None
            wx, wy = ox + (path[target, 1] + 0.5) * cell_m, oy + (path[target, 0] + 0.5) * cell_m
            actions[r] = heading_action(poses[r], (wx, wy), self._tolerance)
        self._last = actions
        return actions

    # ------------------------------------------------------------------ internals
    def _bump(self, r: int) -> None:
        """The robot's last FORWARD was blocked by an obstacle it has not mapped (beside or behind
        the camera's view): the cells its centre would have crossed become impassable for planning,
        like the collision map of Chaplot et al. (2020)."""
        scene = self.world.scene
        assert scene is not None
        pose = self.world.poses[r]
        here = scene.world_to_cell(pose[:2])
        steps = np.linspace(self._cell_m / 2, self.world.config.robot.forward_m, 6)
        ahead = pose[:2] + steps[:, None] * np.array([math.cos(pose[2]), math.sin(pose[2])])
        for cell in scene.world_to_cell(ahead):
            if (
                not np.array_equal(cell, here)
                and 0 <= cell[0] < self._bumps.shape[0]
                and 0 <= cell[1] < self._bumps.shape[1]
            ):
                self._bumps[cell[0], cell[1]] = True
                self._bump_log.append((self.world.metrics.steps + self.config.bump_memory_steps, cell[0], cell[1]))
        self._window_key = None  # the planning grid changed

    def _forget_bumps(self) -> None:
        """Bumped cells are impassable for ``bump_memory_steps`` steps only (the bump may have come
        from a pose the robot will not take again; a permanent mark could wall a robot in)."""
        now = self.world.metrics.steps
        while self._bump_log and self._bump_log[0][0] <= now:
            _, y, x = self._bump_log.popleft()
            if not any(t > now and (yy, xx) == (y, x) for t, yy, xx in self._bump_log):
                self._bumps[y, x] = False
            self._window_key = None

    def _look_around(self, r: int, goal: np.ndarray) -> int:
        """Arrived: turn to face the nearest frontier cell within ``look_radius_m`` of the goal (so a
        frontier is seen, not just reached), then stay; :attr:`settled` says the robot is done."""
        if self.settled[r]:
            return int(Action.STAY)
        world = self.world
        mapper, scene = world.mapper, world.scene
        assert mapper is not None and scene is not None
        here = scene.world_to_cell(world.poses[r, :2])
        fy, fx = _nearest_frontier(mapper.explored, mapper.occupied, goal, self._look_cells, here)
        if fy < 0:
            self.settled[r] = True
            return int(Action.STAY)
        look = (scene.origin_xy[0] + (fx + 0.5) * scene.cell_m, scene.origin_xy[1] + (fy + 0.5) * scene.cell_m)
        action = heading_action(world.poses[r], look, self._view_half)
        if action == Action.FORWARD:
            self.settled[r] = True
            return int(Action.STAY)
        return action

    def _replan(self, r: int, cells: np.ndarray, avoid_robots: bool) -> np.ndarray | None:
        """FMM path for robot ``r``: first in a window around the robot and its goal grown by
        ``local_margin_m`` (cheap), then, if that finds none, over the whole planning window. A
        detour round team-mates (``avoid_robots``) is sought in the local window only."""
        self.replans += 1
        mapper = self.world.mapper
        assert mapper is not None
        margin = round(self.config.local_margin_m / self._cell_m)
        pair = np.stack([cells[r], self.goals[r]])
        local_box = region_box(np.zeros((0, 0), dtype=bool), margin, pair, shape=mapper.explored.shape)
        for window in (local_box,) if avoid_robots else (local_box, None):
            box, passable = self._planning_window(cells, window)
            grid = passable.copy()
            local = cells - box.origin
            if avoid_robots:
                # other robots block a disc of two radii around their centres
                block = disc_offsets(2 * self._radius_m / self._cell_m)
                for o in range(len(cells)):
                    if o != r:
                        ys = np.clip(local[o, 0] + block[:, 0], 0, grid.shape[0] - 1)
                        xs = np.clip(local[o, 1] + block[:, 1], 0, grid.shape[1] - 1)
                        grid[ys, xs] = False
                grid[local[r, 0], local[r, 1]] = True
            path = plan_path(grid, local[r], self.goals[r] - box.origin, self._cell_m)
            if len(path):
                self._grids[r] = (box, grid)
                return path + box.origin
        return None

    def _planning_window(self, cells: np.ndarray, box: Box | None) -> tuple[Box, np.ndarray]:
        """Passable cells for planning now, in ``box`` (None: the whole explored region), cached per step."""
        mapper = self.world.mapper
        assert mapper is not None
        key = (self.world.metrics.steps, box)
        if self._window_key == key and self._window_cache is not None:
            return self._window_cache
        goals = self.goals[self.goals[:, 0] >= 0]
        box, passable, _ = planning_window(
            mapper.explored,
            mapper.occupied,
            cells,
            goals,
            cell_m=self._cell_m,
            radius_m=self._radius_m,
            unknown_margin_m=self.config.unknown_margin_m,
            box=box,
        )
        passable &= ~self._bumps[box.slices]
        inside = (cells >= box.origin).all(axis=1) & (cells < (box.y1, box.x1)).all(axis=1)
        passable[cells[inside, 0] - box.y0, cells[inside, 1] - box.x0] = True
        self._window_cache, self._window_key = (box, passable), key
        return box, passable
