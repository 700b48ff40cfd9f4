"""Jams of any number of robots (not in the paper): holding for team-mates, and a deadlock detector.

Two rules, both on top of the pairwise :mod:`~areasearch.planning.paths.give_way`:

* **Holding** (:func:`hold_kernel`): a FORWARD whose end would overlap a team-mate's footprint, by the
  world's own rule and order (robots move in index order, each seeing the moves of those before it),
  is replaced by STAY, and the robot is treated on the next step exactly as if the world had blocked
  it by a team-mate (``blocked_by`` = robot): it waits, seeks a detour, gives way as before. The robots
  move exactly as they would have (a blocked FORWARD does not move a robot either), but the move is
  never tried, so the collision count of a team counts bumps, not waiting in a queue. A real robot
  that knows where its team-mates are does the same.
* **Deadlock detector** (:meth:`Jams.resolve`): a robot with a goal that has not moved for
  ``deadlock_steps`` steps and that team-mates blocked since it last moved is in a jam. If a
  team-mate that arrived at its own goal stands where it would have to be to arrive (two robots sent
  to one place), its goal is
  taken: it counts as unreachable, and the caller (the high-level environment) gives it another.
  Otherwise the jam is the group of robots
  within ``2 * radius + 2 * forward_m`` of it, transitively. The robot of the group closest to its
  goal (the fewest path cells left; the lower index on a tie) has priority: every other robot of
  the group backs off to the nearest cell off its way (clear of its footprint, its next move and
  its path ahead; :meth:`~areasearch.planning.paths.give_way.GiveWay.find_spot`), a robot without a goal as
  to a goal, a robot with one as when it gives way (it waits there and ``give_way_steps`` after it
  began goes on to its own goal). A robot that finds no such cell this time (hemmed in by the
  others) is tried again at the next detection, once the others have moved; the group's counters
  restart, so a jam is resolved step by step from its edges inwards. Without it, three robots sent to
  one target in a dead end (or meeting in a corridor) stood blocked by one another for the rest of an
  episode: pairwise giving way picks a pair, and in a group of three the pair may have nowhere to go.

:class:`Jams` holds what the two rules keep: the robots held, the steps each robot has stood still,
the jams seen.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ...sim.footprint import point_segment_d2
from ..grid import disc_offsets
from .context import Goals, PlannerContext
from .follow import Follower
from .give_way import GiveWay, Spot
from .state import FORWARD, STAY


@numba.njit(cache=True, nogil=True)
def hold_kernel(poses: np.ndarray, actions: np.ndarray, forward_m: float, min_sep2: float, held: np.ndarray) -> int:
    """Replace by STAY each FORWARD of ``actions`` that would bring the robot's centre within
    ``sqrt(min_sep2)`` of a team-mate's on the way (the world's rule), with the robots moving in
    index order as the world moves them (a robot before it that drives forward is where its move
    ends); ``held`` (R,) says which. Returns how many."""
    n = poses.shape[0]
    px = poses[:, 0].copy()
    py = poses[:, 1].copy()
    count = 0
    for r in range(n):
        held[r] = False
        if actions[r] != FORWARD:
            continue
        nx = px[r] + math.cos(poses[r, 2]) * forward_m
        ny = py[r] + math.sin(poses[r, 2]) * forward_m
        for o in range(n):
            if o != r and point_segment_d2(px[o], py[o], px[r], py[r], nx, ny) < min_sep2:
                held[r] = True
                break
        if held[r]:
            actions[r] = STAY
            count += 1
        else:
            px[r] = nx
            py[r] = ny
    return count


@numba.njit(cache=True, nogil=True)
def track_kernel(
    poses: np.ndarray,
    last_xy: np.ndarray,
    still: np.ndarray,
    waits: np.ndarray,
    making_way: np.ndarray,
    making_way_for: np.ndarray,
    wait_limit: int,
    deadlock_steps: int,
) -> bool:
    """Once per step: count the steps each robot has not changed position (``still``), remember the
    positions; for each robot making way for another (``making_way`` > 0, counted down), keep both
    robots' blocked tries (``waits``) below ``wait_limit``, so neither goal becomes unreachable by
    waiting meanwhile. True if some robot may be in a jam (still for ``deadlock_steps`` and blocked
    by a team-mate since it last moved)."""
    n = poses.shape[0]
    for r in range(n):
        if poses[r, 0] != last_xy[r, 0] or poses[r, 1] != last_xy[r, 1]:
            still[r] = 0
            last_xy[r, 0] = poses[r, 0]
            last_xy[r, 1] = poses[r, 1]
        else:
            still[r] += 1
    for r in range(n):
        if making_way[r] > 0:
            making_way[r] -= 1
            o = making_way_for[r]
            if waits[r] > wait_limit - 1:
                waits[r] = wait_limit - 1
            if o >= 0 and waits[o] > wait_limit - 1:
                waits[o] = wait_limit - 1
    if n < 2:
        return False
    for r in range(n):
        if still[r] >= deadlock_steps and waits[r] > 0:
            return True
    return False


def jam_group(poses: np.ndarray, r: int, reach_m: float) -> list[int]:
    """Robot ``r`` and every robot within ``reach_m`` of the group, transitively, in index order."""
    group, frontier = {r}, [r]
    while frontier:
        o = frontier.pop()
        near = np.flatnonzero(np.hypot(*(poses[:, :2] - poses[o, :2]).T) <= reach_m)
        for k in near.tolist():
            if k not in group:
                group.add(k)
                frontier.append(k)
    return sorted(group)


class Jams:
    """The jam rules' state: the robots whose FORWARD was held, each robot's steps without moving,
    and the jams seen (:meth:`resolve`)."""

    def __init__(self, context: PlannerContext, goals: Goals, follower: Follower, give_way: GiveWay) -> None:
        n = context.num_robots
        self._context, self._goals, self._follower, self._give_way = context, goals, follower, give_way
        self.held = np.zeros(n, dtype=bool)
        """(R,) bool: the robots whose FORWARD of the last step was replaced by STAY because it would
        have run into a team-mate (:func:`hold_kernel`), or that wait for team-mates otherwise."""
        self.resolved = 0
        """Robots sent to back off the way of another in a jam since the reset (:meth:`resolve`)."""
        self._still = np.zeros(n, dtype=np.int64)  # steps since each robot last changed position
        self._last_xy = context.world.believed_poses[:, :2].copy()
        self._seen: dict[tuple[int, ...], tuple[np.ndarray, int]] = {}
        """Per jam group (robot indices): the poses when it was last resolved and how many times
        running it has been found again with nobody moved since (:meth:`resolve`)."""

    def track(self, blocked_by: np.ndarray) -> None:
        """Once per step, before the step kernel: count the steps each robot stood still, count down
        the making way (:func:`track_kernel`), and resolve the jams if some robot may be in one."""
        context, give_way = self._context, self._give_way
        world = context.world
        if track_kernel(
            world.believed_poses, self._last_xy, self._still, self._follower.waits, give_way.making_way,
            give_way.making_way_for, context.config.robot_wait_limit, context.config.deadlock_steps,
        ):  # fmt: skip
            cells = world.scene.world_to_cell(world.believed_poses[:, :2])  # type: ignore[union-attr]
            self.resolved += self.resolve(blocked_by, cells)

    def hold(self, actions: np.ndarray, waiting: np.ndarray) -> None:
        """After the step's actions are chosen: hold each FORWARD that would run into a team-mate
        (:func:`hold_kernel`); the robots ``waiting`` for team-mates count as held too."""
        context = self._context
        hold_kernel(
            context.world.believed_poses,
            actions,
            context.world.config.robot.forward_m,
            context.move_params[5],
            self.held,
        )
        self.held |= waiting

    def resolve(self, blocked_by: np.ndarray, cells: np.ndarray) -> int:
        """Find the robots in a jam (see the module docstring) and make the others of each jam back off
        the way of its robot with priority. Returns how many robots were sent to back off."""
        context, goals, still = self._context, self._goals, self._still
        jammed = [
            r
            for r in np.flatnonzero((still >= context.config.deadlock_steps) & (self._follower.waits > 0)).tolist()
            if goals.has_goal(r) and not self._give_way.active(r)
        ]
        if not jammed:
            return 0
        poses = context.world.believed_poses
        reach = 2 * context.radius_m + 2 * context.world.config.robot.forward_m
        sent = 0
        done: set[int] = set()
        for r in jammed:
            if r in done:
                continue
            if self._goal_taken(r):
                goals.unreachable[r] = True  # the caller gives it another goal
                still[r] = 0
                continue
            group = jam_group(poses, r, reach)
            done.update(group)
            still[group] = 0
            key = tuple(group)
            before = self._seen.get(key)
            again = before[1] + 1 if before is not None and np.array_equal(before[0], poses[group]) else 0
            self._seen[key] = (poses[group].copy(), again)
            plan = self._best_plan(group, cells, again)
            if plan is None:
                continue
            first, spots = plan
            for mover, spot in spots.items():
                self._back_off(mover, spot)
                self._give_way.make_way(mover, first)
                sent += 1
            self._follower.reset_tries(first)
        return sent

    def in_the_way(self, passer: int, cells: np.ndarray, group: list[int]) -> list[int]:
        """The robots of ``group`` whose footprint overlaps ``passer``'s path ahead (the next
        ``4 * local_margin_m`` of it, from the path cell nearest it), farthest from ``passer`` first."""
        context = self._context
        ahead = self._follower.path_ahead(passer, 4 * context.local_margin)
        if len(ahead) == 0:
            return []
        near = (2 * context.radius_m) / context.cell_m + 1
        out = []
        for o in group:
            if o != passer and float(np.hypot(*(ahead - cells[o]).T).min()) <= near:
                out.append((float(np.hypot(*(cells[o] - cells[passer]))), o))
        return [o for _, o in sorted(out, reverse=True)]

    def _best_plan(self, group: list[int], cells: np.ndarray, again: int = 0) -> tuple[int, dict[int, Spot]] | None:
        """The robot of ``group`` to give priority and a spot for each robot in its way: among the robots
        of the group that team-mates block (not those giving way or backing off themselves), tried in
        order of the fewest path cells left (the lower index on a tie), the first for which every robot
        in its way finds a spot (searched within twice, then four times ``local_margin_m``, the
        farthest from it first, each free to pass through the robots moving off before it, round and
        clear of their spots); else the one for which the most do. None when no plan moves anyone.

        ``again``: how many times running the same group was found jammed with nobody moved since the
        last plan (a gridlock: the robots backing off are held by one another). The order then starts
        ``again`` places further on (cyclically), so that another robot gets priority and the others
        back off other ways, rather than the same plan failing for the rest of the episode (five robots
        in a corridor's dead end, run S4)."""
        follower, give_way, margin = self._follower, self._give_way, self._context.local_margin
        order = sorted(
            (follower.cells_left(o), o)
            for o in group
            if self._goals.has_goal(o)
            and follower.has_path(o)
            and follower.waits[o] > 0
            and not give_way.active(o)
            and give_way.making_way[o] == 0
        )
        if order and again:
            shift = again % len(order)
            order = order[shift:] + order[:shift]
        best: tuple[int, dict[int, Spot]] | None = None
        best_missing = 10**9
        for _, first in order:
            movers = self.in_the_way(first, cells, group)
            if not movers:
                continue
            spots: dict[int, Spot] = {}
            for mover in movers:
                for cells_off in (2 * margin, 4 * margin):
                    taken = [other.cell for other in spots.values()]
                    spot = give_way.find_spot(mover, first, cells, cells_off, moving=list(spots), taken=taken)
                    if spot is not None:
                        spots[mover] = spot
                        break
            missing = len(movers) - len(spots)
            if spots and missing < best_missing:
                best, best_missing = (first, spots), missing
            if missing == 0:
                break
        return best

    def _goal_taken(self, r: int) -> bool:
        """Team-mates that arrived at their own goals stand where robot ``r``'s footprint would have to
        be to arrive at ``r``'s goal (two robots sent to one place): every cell within ``r``'s arrival
        distance of its goal that the map shows clear for a robot centre overlaps one of their
        footprints, so ``r`` cannot get there while they stay."""
        context, goals = self._context, self._goals
        arrived = goals.reached.copy()
        arrived[r] = False
        if not arrived.any():
            return False
        cell_m = context.cell_m
        blocked = context.inflated_obstacles(r)
        h, w = blocked.shape
        disc = disc_offsets(goals.tolerances_m[r] / cell_m)
        cells = goals.cells[r] + disc
        inside = (cells[:, 0] >= 0) & (cells[:, 0] < h) & (cells[:, 1] >= 0) & (cells[:, 1] < w)
        cells = cells[inside]
        cells = cells[~blocked[cells[:, 0], cells[:, 1]]]
        if len(cells) == 0:
            return False  # nothing known to stand on there: not a question of team-mates
        xy = context.world.scene.cell_to_world(cells)  # type: ignore[union-attr]
        others = context.world.believed_poses[arrived, :2]
        free = (np.hypot(*(xy[:, None, :] - others[None, :, :]).transpose(2, 0, 1)) >= 2 * context.radius_m).all(axis=1)
        return not bool(free.any())

    def _back_off(self, mover: int, spot: Spot) -> None:
        """Send ``mover`` to ``spot``: as its goal when it has none (or has arrived), else to wait there
        as a robot giving way does (:meth:`~areasearch.planning.paths.give_way.GiveWay.carry_on`)."""
        cell = self._give_way.take_spot(mover, spot)
        if not self._goals.has_goal(mover) and not self._give_way.active(mover):
            # no goal, or arrived: the spot becomes its goal until the next decision (an arrived robot
            # stays where it arrived, so waiting somewhere and going back would not help)
            self._goals.send(mover, cell, self._context.cell_m)
            self._goals.approach_xy[mover] = np.nan
            self._follower.reset_tries(mover)
            return
        self._give_way.wait_at(mover, cell)
