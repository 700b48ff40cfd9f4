"""Primitive search: the last moves planned with the motion primitives themselves.

The heading heuristic cuts corners: it could not enter a way in barely wider than the robot (it
bumped, and its bump marks closed the way in on the planning grid). So a FORWARD that would bump into
a mapped obstacle by the world's own rule (:func:`bumps_ahead`) is replaced by a plan of primitive
moves, A* over the poses FORWARD and the turns reach (:func:`primitive_search`, each FORWARD checked
by :func:`_forward_clear` as the world checks it) on the space the map shows free
(:meth:`Primitives.known_obstacles`), to the goal if it lies within ``primitive_search_m``, else to
the path that far ahead; the robot follows the plan move by move (:meth:`Primitives.step`).

Approach points: a robot whose goal is a point it must drive its centre over (a target under the
``paper`` protocol) arrives once a move of it sweeps its centre within the cover radius of the point
(measured by :func:`_segment_distance` as the world measures it;
:meth:`Primitives.arrival_tolerances` tells the step kernel), and within ``primitive_search_m`` of
the point plans its moves over it (:meth:`Primitives.approach_due`). A search that finds no plan is
not tried again for ``primitive_search_pause_steps`` steps.

:class:`Primitives` holds the plans, the failed searches and the approach points passed.
"""

from __future__ import annotations

import heapq
import math

import numba
import numpy as np

from ...sim.footprint import footprint_offsets, point_segment_d2, segment_hits
from ...sim.world import wrap_angle
from ..grid import Box, inflate_kernel
from .context import Goals, PlannerContext
from .follow import Follower
from .give_way import GiveWay
from .state import F_CELL, F_OX, F_OY, FORWARD, OBSTACLE, STAY, TURN_LEFT, TURN_RIGHT

MAX_MOVES = 128
"""Longest plan a primitive search returns, actions."""


# ---------------------------------------------------------------------------------- kernels


@numba.njit(cache=True, nogil=True)
def _forward_clear(
    obstacles: np.ndarray,
    y0: int,
    x0: int,
    ox: float,
    oy: float,
    cell_m: float,
    x: float,
    y: float,
    yaw: float,
    forward_m: float,
    radius_m: float,
    others: np.ndarray,
    min_sep2: float,
) -> bool:
    """Would a FORWARD from (x, y, yaw) pass, by the world's own rule (``world._move_kernel``: the
    footprint swept along the move overlaps no obstacle cell, and the centre keeps ``min_sep2`` from
    every other robot's on the way), among ``obstacles`` (a window with first cell (y0, x0); outside
    it counts as obstacle)?"""
    nx, ny = x + math.cos(yaw) * forward_m, y + math.sin(yaw) * forward_m
    if segment_hits(obstacles, y0, x0, ox, oy, cell_m, x, y, nx, ny, radius_m):
        return False
    for o in range(others.shape[0]):
        if point_segment_d2(others[o, 0], others[o, 1], x, y, nx, ny) < min_sep2:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def bumps_ahead(
    occupied: np.ndarray,
    radius_m: float,
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
    """``out[r]``: robot ``r``'s FORWARD would sweep its footprint over a mapped obstacle, so the
    world would block it (the world's rule, :func:`~areasearch.sim.footprint.segment_hits`, on the
    mapped obstacles; the map's edge is not an obstacle here); robots that follow a plan of moves or
    whose last search failed after step ``failed_before`` are not checked. True if some robot needs
    :meth:`Primitives.step` (a plan to follow or a bump ahead)."""
    h, w = occupied.shape
    reach = int(math.ceil(radius_m / cell_m + forward_m / cell_m)) + 1
    anything = False
    for r in range(poses.shape[0]):
        out[r] = False
        if moves_len[r] > 0:
            anything = True
            continue
        if actions[r] != FORWARD or moves_failed[r] > failed_before:
            continue
        x, y = poses[r, 0], poses[r, 1]
        iy = int(math.floor((y - oy) / cell_m))
        ix = int(math.floor((x - ox) / cell_m))
        y0, y1 = max(iy - reach, 0), min(iy + reach + 1, h)
        x0, x1 = max(ix - reach, 0), min(ix + reach + 1, w)
        if y0 >= y1 or x0 >= x1:
            continue
        window = occupied[y0:y1, x0:x1]  # every cell the move's footprint can reach
        nx, ny = x + math.cos(poses[r, 2]) * forward_m, y + math.sin(poses[r, 2]) * forward_m
        if segment_hits(window, y0, x0, ox, oy, cell_m, x, y, nx, ny, radius_m, False):
            out[r] = True
            anything = True
    return anything


@numba.njit(cache=True, nogil=True)
def primitive_search(
    obstacles: np.ndarray,
    y0: int,
    x0: int,
    ox: float,
    oy: float,
    cell_m: float,
    pose: np.ndarray,
    forward_m: float,
    turn_rad: float,
    radius_m: float,
    others: np.ndarray,
    min_sep2: float,
    gx: float,
    gy: float,
    tolerance: float,
    swept: bool,
    max_expand: int,
    out: np.ndarray,
) -> int:
    """Shortest sequence of primitive actions (FORWARD, TURN_LEFT, TURN_RIGHT; one step each) that
    brings a robot at ``pose`` within ``tolerance`` of (gx, gy) without a blocked move, by A* over
    the poses the primitives reach (exactly as the world moves a robot; poses in one cell with one
    heading count as one). With ``swept``, a FORWARD whose swept segment passes within ``tolerance``
    of (gx, gy) reaches it (the ``paper`` protocol's cover rule), else only the pose after a move
    counts. Writes the actions to ``out`` and returns how many, or -1 if none is found within
    ``max_expand`` expansions or ``len(out)`` actions."""
    h, w = obstacles.shape
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
        for a in (FORWARD, TURN_LEFT, TURN_RIGHT):
            x, y, yaw, k = xs[i], ys[i], yaws[i], head[i]
            if a == FORWARD:
                if not _forward_clear(
                    obstacles, y0, x0, ox, oy, cell_m, x, y, yaw, forward_m, radius_m, others, min_sep2
                ):
                    continue
                x += math.cos(yaw) * forward_m
                y += math.sin(yaw) * forward_m
            elif a == TURN_LEFT:
                yaw = wrap_angle(yaw + turn_rad)
                k = (k + 1) % n_head
            else:
                yaw = wrap_angle(yaw - turn_rad)
                k = (k - 1) % n_head
            cy = int(math.floor((y - oy) / cell_m)) - y0
            cx = int(math.floor((x - ox) / cell_m)) - x0
            if seen[cy, cx, k]:
                continue
            seen[cy, cx, k] = True
            xs[n], ys[n], yaws[n], head[n], depth[n], parent[n], move[n] = x, y, yaw, k, depth[i] + 1, i, a
            d = math.hypot(gx - x, gy - y)
            if swept and a == FORWARD and d > tolerance and _segment_distance(xs[i], ys[i], x, y, gx, gy) <= tolerance:
                d = 0.0
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
def _segment_distance(ax: float, ay: float, bx: float, by: float, px: float, py: float) -> float:
    """Distance from (px, py) to the segment (ax, ay)-(bx, by), as the world's swept cover check
    measures it."""
    sx, sy = bx - ax, by - ay
    dx, dy = px - ax, py - ay
    length2 = sx * sx + sy * sy
    if length2 > 0.0:
        t = min(1.0, max(0.0, (dx * sx + dy * sy) / length2))
        dx -= t * sx
        dy -= t * sy
    return math.sqrt(dx * dx + dy * dy)


@numba.njit(cache=True, nogil=True)
def _plan_clear(
    moves: np.ndarray,
    length: int,
    pose: np.ndarray,
    forward_m: float,
    turn_rad: float,
    others: np.ndarray,
    min_sep2: float,
) -> bool:
    """Whether every FORWARD of the plan ``moves[:length]`` from ``pose`` keeps its centre
    ``min_sep2`` clear of every robot of ``others`` (standing still) on the way: the world's rule
    for team-mates."""
    x, y, yaw = pose[0], pose[1], pose[2]
    for i in range(length):
        a = moves[i]
        if a == FORWARD:
            nx, ny = x + math.cos(yaw) * forward_m, y + math.sin(yaw) * forward_m
            for o in range(others.shape[0]):
                if point_segment_d2(others[o, 0], others[o, 1], x, y, nx, ny) < min_sep2:
                    return False
            x, y = nx, ny
        elif a == TURN_LEFT:
            yaw = wrap_angle(yaw + turn_rad)
        else:
            yaw = wrap_angle(yaw - turn_rad)
    return True


def narrow_here(blocked: np.ndarray, iy: int, ix: int, reach: int = 6, thin_cells: int = 5) -> bool:
    """Whether a narrow passage lies within ``reach`` cells of the cell (iy, ix) of the window
    ``blocked`` (True where no robot centre may stand): at least ``thin_cells`` cells there where a
    centre may stand have at most two such cells among their four neighbours, as the cells of a
    way through a doorway barely wider than the robot have (one or two cells across; in the open
    only the convex corners of the space a centre may stand on are such cells, one per corner).
    There, a way through may take many more moves and poses to find than in the open."""
    h, w = blocked.shape
    y0, y1 = max(iy - reach - 1, 0), min(iy + reach + 2, h)
    x0, x1 = max(ix - reach - 1, 0), min(ix + reach + 2, w)
    free = np.pad(~blocked[y0:y1, x0:x1], 1)
    neighbours = free[:-2, 1:-1].astype(np.int8) + free[2:, 1:-1] + free[1:-1, :-2] + free[1:-1, 2:]
    thin = free[1:-1, 1:-1] & (neighbours <= 2)
    return int(thin.sum()) >= thin_cells


def _inflated(obstacles: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Where a robot centre may not stand among ``obstacles`` (a window)."""
    blocked = np.zeros(obstacles.shape, dtype=bool)
    inflate_kernel(obstacles, offsets, blocked)
    return blocked


# ---------------------------------------------------------------------------------- the part


class Primitives:
    """The robots' plans of primitive moves and their approach points: per robot the plan, the next
    action of it, the step of the last search that found none, and whether it has driven over its
    approach point since its goal was set."""

    def __init__(self, context: PlannerContext, goals: Goals, follower: Follower, give_way: GiveWay) -> None:
        n = context.num_robots
        self._context, self._goals, self._follower, self._give_way = context, goals, follower, give_way
        self._bump_ahead = np.zeros(n, dtype=np.bool_)
        self._moves = np.zeros((n, MAX_MOVES), dtype=np.int64)  # primitive-search plans, per robot
        self._moves_len = np.zeros(n, dtype=np.int64)  # 0: none
        self._moves_at = np.zeros(n, dtype=np.int64)  # next action of the plan
        self.failed_at = np.full(n, -(10**9), dtype=np.int64)
        """(R,) step of each robot's last search that found no plan."""
        self.passed = np.zeros(n, dtype=bool)
        """(R,) bool: drove over its approach point since its goal was set."""
        self._narrow_tried = np.full((n, 2), -1, dtype=np.int64)  # cell of the last long search in a narrow way
        self._wait_key = [np.zeros(0)] * n  # poses and goal of the last wait for team-mates
        self._kernel_tol = goals.tolerances_m.copy()  # arrival distances as the step kernel reads them
        self.waiting = np.zeros(n, dtype=bool)
        """(R,) bool: the robots a primitive search of the last step found a way in for only without the
        team-mates (they wait for them, counted as held)."""

    def new_approach(self, r: int) -> None:
        """Robot ``r`` has a new point to drive over (or none): not passed, no plan."""
        self.passed[r] = False
        self._moves_len[r] = 0

    def new_goal(self, r: int) -> None:
        """Robot ``r`` has a new goal: no plan, no failed search, its approach point not passed."""
        self._moves_len[r] = 0
        self.failed_at[r] = -(10**9)
        self.passed[r] = False

    def step(self, actions: np.ndarray, blocked_by: np.ndarray) -> None:
        """Where the heading heuristic would drive a robot into a mapped obstacle (a narrow way in, a
        corner cut too close), plan the next moves with the primitives themselves
        (:func:`primitive_search`) and follow that plan; a plan is dropped when a move of it is
        blocked (an unmapped obstacle, a team-mate), the goal changes, or it is done."""
        self.waiting[:] = False
        world = self._context.world
        mapper = world.mapper
        now = world.metrics.steps
        pause = self._context.config.primitive_search_pause_steps
        ox, oy, cell_m, forward_m, _, _, radius = self._context.move_params
        if not bumps_ahead(
            mapper.occupied, radius, ox, oy, cell_m, world.believed_poses, actions, forward_m,  # type: ignore[union-attr]
            self._moves_len, self.failed_at, now - pause, self._bump_ahead,
        ) and not self.approach_due(now):  # fmt: skip
            return  # no plan to follow, no FORWARD into a mapped obstacle: nothing to do (most steps)
        goals = self._goals
        for r in range(len(goals)):
            yielding = self._give_way.active(r)  # driving to a spot off a team-mate's way
            if goals.cells[r, 0] < 0 or goals.unreachable[r] or (goals.reached[r] and not yielding):
                self._moves_len[r] = 0
                continue
            if self._moves_len[r]:
                if blocked_by[r] != 0 or self._moves_at[r] >= self._moves_len[r]:
                    if blocked_by[r] == OBSTACLE:
                        self.failed_at[r] = now  # an obstacle the map does not show: no new search soon
                    self._moves_len[r] = 0
                else:
                    self._follower.take(r, int(self._moves[r, self._moves_at[r]]), actions)
                    self._moves_at[r] += 1
                    continue
            if not self._bump_ahead[r] and not (self.failed_at[r] <= now - pause and self._approaching(r)):
                continue
            self._plan(r, actions, now)

    def _plan(self, r: int, actions: np.ndarray, now: int) -> None:
        """Search robot ``r`` a plan of moves (see :meth:`step`) and take its first move; or wait for
        the team-mates when only they are in the way; or note that no plan was found."""
        mapper = self._context.map_of(r)
        poses = self._context.world.believed_poses
        ox, oy, cell_m, forward_m, turn_rad, min_sep2, radius = self._context.move_params
        others = np.delete(poses[:, :2], r, axis=0)
        gx, gy, tolerance, swept = self._search_goal(r)
        m = math.ceil((self._context.config.primitive_search_m / 2 + forward_m + radius) / cell_m)
        here = np.floor((poses[r, 1::-1] - (oy, ox)) / cell_m).astype(np.int64)
        there = np.floor((np.array([gy, gx]) - (oy, ox)) / cell_m).astype(np.int64)
        h, w = mapper.shape
        y0, x0 = max(min(here[0], there[0]) - m, 0), max(min(here[1], there[1]) - m, 0)
        y1, x1 = min(max(here[0], there[0]) + m + 1, h), min(max(here[1], there[1]) + m + 1, w)
        obstacles, (y0, x0) = self.known_obstacles(Box(y0, y1, x0, x1), r)
        pose = poses[r]
        # what the search depends on: the poses, the goal, the window of the map (explored and
        # occupied cells only ever grow, so their counts tell whether it changed)
        window = Box(y0, y0 + obstacles.shape[0], x0, x0 + obstacles.shape[1]).slices
        seen = (float(mapper.explored[window].sum()), float(mapper.occupied[window].sum()))
        key = np.concatenate([pose, others.ravel(), (gx, gy, tolerance, float(swept), *seen)])
        if len(others) and np.array_equal(key, self._wait_key[r]):
            # nothing moved since a search found that only team-mates are in the way: the same again
            actions[r] = STAY
            self.waiting[r] = True
            return
        # first without team-mates: a plan that also keeps clear of them is a shortest one with
        # them; no plan at all means none with them either (a full search that fails costs the
        # whole budget, a relaxed one that succeeds little)
        length = self._search(obstacles, y0, x0, pose, others[:0], gx, gy, tolerance, swept, here, r)
        if (
            length > 0
            and len(others)
            and not _plan_clear(self._moves[r], length, pose, forward_m, turn_rad, others, min_sep2)
        ):
            relaxed = length
            # a team-mate standing within two radii less the tolerance of the point: no move of the
            # robot can come within the tolerance of it while the team-mate stays (the world's rule)
            taken = bool((np.hypot(others[:, 0] - gx, others[:, 1] - gy) + tolerance < 2 * radius).any())
            length = -1 if taken else self._search(obstacles, y0, x0, pose, others, gx, gy, tolerance, swept, here, r)
            if length <= 0 and actions[r] == FORWARD and relaxed > 0:
                # only team-mates are in the way: wait for them (as for a team-mate that blocked a
                # FORWARD) rather than drive into the obstacle, and search again once something moved
                self._wait_key[r] = key
                actions[r] = STAY
                self.waiting[r] = True
                return
        if length <= 0:
            self.failed_at[r] = now
            return
        self._moves_len[r] = length
        self._moves_at[r] = 1
        self._follower.take(r, int(self._moves[r, 0]), actions)

    def _search(
        self,
        obstacles: np.ndarray,
        y0: int,
        x0: int,
        pose: np.ndarray,
        others: np.ndarray,
        gx: float,
        gy: float,
        tolerance: float,
        swept: bool,
        here: np.ndarray,
        r: int,
    ) -> int:
        """One primitive search for robot ``r`` into its plan buffer: ``primitive_search_expansions``
        poses, and if that finds none near a narrow passage, once per cell it stands in,
        ``primitive_search_narrow_expansions`` (asked without team-mates, the search of the geometry
        alone, the long one is the relaxed search's)."""
        cfg = self._context.config
        ox, oy, cell_m, forward_m, turn_rad, min_sep2, radius = self._context.move_params
        length: int = primitive_search(
            obstacles, y0, x0, ox, oy, cell_m, pose, forward_m, turn_rad, radius, others, min_sep2,
            gx, gy, tolerance, swept, cfg.primitive_search_expansions, self._moves[r],
        )  # fmt: skip
        if (
            length <= 0
            and len(others) == 0
            and cfg.primitive_search_narrow_expansions > cfg.primitive_search_expansions
        ):
            tried = self._narrow_tried[r]
            if (tried[0], tried[1]) != (here[0], here[1]) and narrow_here(
                _inflated(obstacles, self._context.offsets), here[0] - y0, here[1] - x0
            ):
                self._narrow_tried[r] = here  # one long search per cell it is stuck in
                length = primitive_search(
                    obstacles, y0, x0, ox, oy, cell_m, pose, forward_m, turn_rad, radius, others, min_sep2,
                    gx, gy, tolerance, swept, cfg.primitive_search_narrow_expansions, self._moves[r],
                )  # fmt: skip
        return length

    def approach_due(self, now: int) -> bool:
        """Some robot without a plan is near a point it must drive over (a new search is due)."""
        ready = ~self.passed & ~np.isnan(self._goals.approach_xy[:, 0]) & (self._moves_len == 0)
        ready &= self.failed_at <= now - self._context.config.primitive_search_pause_steps
        return any(self._approaching(int(r)) for r in np.flatnonzero(ready))

    def known_obstacles(self, box: Box, r: int) -> tuple[np.ndarray, tuple[int, int]]:
        """The obstacle cells a primitive plan for robot ``r`` must keep its footprint off, round
        ``box`` (grown by the footprint's reach, so that every centre in ``box`` is judged on all the
        cells its footprint may overlap), and the first cell (y0, x0) of that window: mapped obstacles
        and unknown cells (a plan keeps to space the map shows free, so that the world lets every move
        of it pass), but for the unknown cells under the robot's own footprint (it stands there: the
        floor a camera cannot see under itself is free)."""
        context = self._context
        mapper = context.map_of(r)
        h, w = mapper.shape
        pad = int(np.abs(context.offsets).max()) + 1
        big = Box(max(box.y0 - pad, 0), min(box.y1 + pad, h), max(box.x0 - pad, 0), min(box.x1 + pad, w))
        occupied = mapper.occupied[big.slices]
        obstacles = ~mapper.explored[big.slices] | occupied
        ox, oy, cell_m = context.move_params[:3]
        pose = context.world.believed_poses[r]
        cy = int(math.floor((pose[1] - oy) / cell_m)) - big.y0
        cx = int(math.floor((pose[0] - ox) / cell_m)) - big.x0
        under = np.array([cy, cx]) + footprint_offsets(cell_m, context.radius_m)
        inside = (under[:, 0] >= 0) & (under[:, 0] < big.shape[0]) & (under[:, 1] >= 0) & (under[:, 1] < big.shape[1])
        under = under[inside]
        obstacles[under[:, 0], under[:, 1]] = occupied[under[:, 0], under[:, 1]]
        return obstacles, (big.y0, big.x0)

    def _search_goal(self, r: int) -> tuple[float, float, float, bool]:
        """Where a primitive search for robot ``r`` aims, and with what tolerance and test: the point
        it must drive its centre over (a target under the ``paper`` protocol: within the cover radius
        along a move's swept segment) if that is within ``primitive_search_m``; else its goal (within
        its arrival tolerance; for a robot giving way, its spot, within a cell) if the goal is that
        close; else the farthest cell of its path ahead within that distance (within half a forward
        step)."""
        context, goals = self._context, self._goals
        yielding = self._give_way.active(r)
        if self._approaching(r) and not yielding:
            ax, ay = goals.approach_xy[r]
            return float(ax), float(ay), context.cover_m, True
        fp = context.fparams
        ox, oy, cell_m = fp[F_OX], fp[F_OY], fp[F_CELL]
        pose = context.world.believed_poses[r]
        reach = context.config.primitive_search_m
        goal = self._give_way.spot(r) if yielding else goals.cells[r]  # a robot giving way: its spot
        gx, gy = ox + (goal[1] + 0.5) * cell_m, oy + (goal[0] + 0.5) * cell_m
        if math.hypot(gx - pose[0], gy - pose[1]) <= reach or not self._follower.has_path(r):
            return gx, gy, cell_m if yielding else float(goals.tolerances_m[r]), False
        ahead = self._follower.path_ahead(r)
        xy = np.stack([ox + (ahead[:, 1] + 0.5) * cell_m, oy + (ahead[:, 0] + 0.5) * cell_m], axis=1)
        within = np.flatnonzero(np.hypot(*(xy - pose[:2]).T) <= reach)
        k = int(within[-1]) if len(within) else 0
        return float(xy[k, 0]), float(xy[k, 1]), context.world.config.robot.forward_m / 2, False

    def _approaching(self, r: int) -> bool:
        """Robot ``r`` has a point to drive over, not yet passed, within ``primitive_search_m``."""
        approach_xy = self._goals.approach_xy
        if self.passed[r] or math.isnan(approach_xy[r, 0]):
            return False
        pose = self._context.world.believed_poses[r]
        ax, ay = approach_xy[r]
        return math.hypot(ax - pose[0], ay - pose[1]) <= self._context.config.primitive_search_m

    def _check_passed(self) -> None:
        """Mark the robots whose last move swept their centre over their approach point (the world's
        ``paper`` cover rule): they have arrived."""
        world, approach_xy = self._context.world, self._goals.approach_xy
        prev, now = world.believed_previous_xy, world.believed_poses
        for r in np.flatnonzero(~self.passed & ~np.isnan(approach_xy[:, 0])):
            ax, ay = approach_xy[r]
            if _segment_distance(prev[r, 0], prev[r, 1], now[r, 0], now[r, 1], ax, ay) <= self._context.cover_m:
                self.passed[r] = True

    def arrival_tolerances(self) -> np.ndarray:
        """(R,) arrival distances for the step kernel: the goals' tolerances, except that a robot with a
        point to drive over arrives once it has (infinite tolerance), at any distance, and never before (-1)."""
        goals = self._goals
        if np.isnan(goals.approach_xy[:, 0]).all():
            return goals.tolerances_m
        self._check_passed()
        tolerances = self._kernel_tol
        tolerances[:] = goals.tolerances_m
        pending_pass = ~np.isnan(goals.approach_xy[:, 0])
        tolerances[pending_pass & self.passed] = np.inf
        tolerances[pending_pass & ~self.passed] = -1.0
        return tolerances
