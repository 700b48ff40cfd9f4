"""Jams of any number of robots (not in the paper): holding for team-mates, and a deadlock detector.

Two rules, both on top of the pairwise :mod:`~areasearch.paths.give_way`:

* **Holding** (:func:`hold_kernel`): a FORWARD whose end would overlap a team-mate's footprint, by the
  world's own rule and order (robots move in index order, each seeing the moves of those before it),
  is replaced by STAY, and the robot is treated on the next step exactly as if the world had blocked
  it by a team-mate (``blocked_by`` = robot): it waits, seeks a detour, gives way as before. The robots
  move exactly as they would have (a blocked FORWARD does not move a robot either), but the move is
  never tried, so the collision count of a team counts bumps, not waiting in a queue. A real robot
  that knows where its team-mates are does the same.
* **Deadlock detector** (:func:`resolve_jams`): a robot with a goal that has not moved for
  ``deadlock_steps`` steps and that team-mates blocked since it last moved is in a jam. If a
  team-mate that arrived at its own goal stands where it would have to be to arrive (two robots sent
  to one place), its goal is
  taken: it counts as unreachable, and the caller (the high-level environment) gives it another.
  Otherwise the jam is the group of robots
  within ``2 * radius + 2 * forward_m`` of it, transitively. The robot of the group closest to its
  goal (the fewest path cells left; the lower index on a tie) has priority: every other robot of
  the group backs off to the nearest cell off its way (clear of its footprint, its next move and
  its path ahead; :func:`~areasearch.paths.give_way.spot_off_the_way`), a robot without a goal as
  to a goal, a robot with one as when it gives way (it waits there and ``give_way_steps`` after it
  began goes on to its own goal). A robot that finds no such cell this time (hemmed in by the
  others) is tried again at the next detection, once the others have moved; the group's counters
  restart, so a jam is resolved step by step from its edges inwards. Without it, three robots sent to
  one target in a dead end (or meeting in a corridor) stood blocked by one another for the rest of an
  episode: pairwise giving way picks a pair, and in a group of three the pair may have nowhere to go.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numba
import numpy as np

from ..footprint import point_segment_d2
from ..geodesic import disc_offsets
from .give_way import Spot, find_spot, take_spot
from .state import FORWARD, LENGTH, PROGRESS, STAY, STUCK, WAITS

if TYPE_CHECKING:
    from .planner import ActionPlanner


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


def resolve_jams(planner: ActionPlanner, blocked_by: np.ndarray, cells: np.ndarray) -> int:
    """Find the robots in a jam (see the module docstring) and make the others of each jam back off
    the way of its robot with priority. Returns how many robots were sent to back off."""
    cfg = planner.config
    still = planner._still
    jammed = [
        r
        for r in np.flatnonzero((still >= cfg.deadlock_steps) & (planner._state[:, WAITS] > 0)).tolist()
        if _has_goal(planner, r) and planner._yield_cell[r, 0] < 0
    ]
    if not jammed:
        return 0
    poses = planner.world.poses
    reach = 2 * planner._radius_m + 2 * planner.world.config.robot.forward_m
    sent = 0
    done: set[int] = set()
    for r in jammed:
        if r in done:
            continue
        if _goal_taken(planner, r):
            planner.unreachable[r] = True  # the caller gives it another goal
            still[r] = 0
            continue
        group = jam_group(poses, r, reach)
        done.update(group)
        still[group] = 0
        key = tuple(group)
        before = planner._jam_seen.get(key)
        again = before[1] + 1 if before is not None and np.array_equal(before[0], poses[group]) else 0
        planner._jam_seen[key] = (poses[group].copy(), again)
        plan = _best_plan(planner, group, cells, again)
        if plan is None:
            continue
        first, spots = plan
        for mover, spot in spots.items():
            _back_off(planner, mover, spot)
            planner.make_way(mover, first)
            sent += 1
        planner._state[first, WAITS] = 0
        planner._state[first, STUCK] = 0
    return sent


def in_the_way(planner: ActionPlanner, passer: int, cells: np.ndarray, group: list[int]) -> list[int]:
    """The robots of ``group`` whose footprint overlaps ``passer``'s path ahead (the next
    ``4 * local_margin_m`` of it, from the path cell nearest it), farthest from ``passer`` first."""
    m = 4 * planner._local_margin
    length, progress = int(planner._state[passer, LENGTH]), int(planner._state[passer, PROGRESS])
    ahead = planner._paths[passer, progress : min(length, progress + m)]
    if len(ahead) == 0:
        return []
    near = (2 * planner._radius_m) / planner._cell_m + 1
    out = []
    for o in group:
        if o != passer and float(np.hypot(*(ahead - cells[o]).T).min()) <= near:
            out.append((float(np.hypot(*(cells[o] - cells[passer]))), o))
    return [o for _, o in sorted(out, reverse=True)]


def _best_plan(
    planner: ActionPlanner, group: list[int], cells: np.ndarray, again: int = 0
) -> tuple[int, dict[int, Spot]] | None:
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
    order = sorted(
        (int(planner._state[o, LENGTH] - planner._state[o, PROGRESS]), o)
        for o in group
        if _has_goal(planner, o)
        and planner._state[o, LENGTH]
        and planner._state[o, WAITS] > 0
        and planner._yield_cell[o, 0] < 0
        and planner._making_way[o] == 0
    )
    if order and again:
        shift = again % len(order)
        order = order[shift:] + order[:shift]
    best: tuple[int, dict[int, Spot]] | None = None
    best_missing = 10**9
    for _, first in order:
        movers = in_the_way(planner, first, cells, group)
        if not movers:
            continue
        spots: dict[int, Spot] = {}
        for mover in movers:
            for margin in (2 * planner._local_margin, 4 * planner._local_margin):
                taken = [other.cell for other in spots.values()]
                spot = find_spot(planner, mover, first, cells, margin, moving=list(spots), taken=taken)
                if spot is not None:
                    spots[mover] = spot
                    break
        missing = len(movers) - len(spots)
        if spots and missing < best_missing:
            best, best_missing = (first, spots), missing
        if missing == 0:
            break
    return best


def _has_goal(planner: ActionPlanner, r: int) -> bool:
    return bool(planner.goals[r, 0] >= 0 and not planner.unreachable[r] and not planner.reached[r])


def _goal_taken(planner: ActionPlanner, r: int) -> bool:
    """Team-mates that arrived at their own goals stand where robot ``r``'s footprint would have to
    be to arrive at ``r``'s goal (two robots sent to one place): every cell within ``r``'s arrival
    distance of its goal that the map shows clear for a robot centre overlaps one of their
    footprints, so ``r`` cannot get there while they stay."""
    arrived = planner.reached.copy()
    arrived[r] = False
    if not arrived.any():
        return False
    cell_m = planner._cell_m
    blocked = planner.inflated_obstacles()
    h, w = blocked.shape
    disc = disc_offsets(planner.tolerances_m[r] / cell_m)
    cells = planner.goals[r] + disc
    inside = (cells[:, 0] >= 0) & (cells[:, 0] < h) & (cells[:, 1] >= 0) & (cells[:, 1] < w)
    cells = cells[inside]
    cells = cells[~blocked[cells[:, 0], cells[:, 1]]]
    if len(cells) == 0:
        return False  # nothing known to stand on there: not a question of team-mates
    xy = planner.world.scene.cell_to_world(cells)  # type: ignore[union-attr]
    others = planner.world.poses[arrived, :2]
    free = (np.hypot(*(xy[:, None, :] - others[None, :, :]).transpose(2, 0, 1)) >= 2 * planner._radius_m).all(axis=1)
    return not bool(free.any())


def _back_off(planner: ActionPlanner, mover: int, spot: Spot) -> None:
    """Send ``mover`` to ``spot``: as its goal when it has none (or has arrived), else to wait there
    as a robot giving way does (:func:`~areasearch.paths.give_way.continue_giving_way`)."""
    cell = take_spot(planner, mover, spot)
    if not _has_goal(planner, mover) and planner._yield_cell[mover, 0] < 0:
        # no goal, or arrived: the spot becomes its goal until the next decision (an arrived robot
        # stays where it arrived, so waiting somewhere and going back would not help)
        planner.goals[mover] = cell
        planner.tolerances_m[mover] = planner._cell_m
        planner.approach_xy[mover] = np.nan
        planner.unreachable[mover] = planner.reached[mover] = planner.settled[mover] = False
        planner._state[mover, STUCK] = planner._state[mover, WAITS] = 0
        return
    planner._yield_cell[mover] = cell
    planner._yield_steps[mover] = 0
