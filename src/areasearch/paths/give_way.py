"""Giving way (not in the paper): two robots that need one narrow passage in opposite ways.

A robot blocked by a team-mate waits, then seeks a detour round the team-mates (the step kernel of
:mod:`~areasearch.paths.follow` asks for one every ``detour_every_steps`` blocked tries). When a
detour has not helped ``detour_every_steps`` steps later, :func:`give_way` makes one of the two move
off the other's way: the team-mate if it has no goal (it drives to the nearest cell off the other's
way as to a goal, :func:`spot_off_the_way`); if both block each other, the one of higher index,
which drives to such a spot, waits there and after ``give_way_steps`` steps goes on to its own goal
(:func:`continue_giving_way`). Without it, two robots facing each other in a corridor could block
each other for the rest of an episode.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ..geodesic import Box, disc_offsets, distance_field
from .follow import block_robots, descend, planning_grid, store_path
from .state import LAST, LENGTH, PROGRESS, ROBOT, STAY, STUCK, WAITS

if TYPE_CHECKING:
    from .planner import ActionPlanner


def _blocker(planner: ActionPlanner, r: int) -> int:
    """The team-mate whose footprint a FORWARD of robot ``r`` would overlap (the nearest one), or -1."""
    poses = planner.world.poses
    step = planner.world.config.robot.forward_m
    ahead = poses[r, :2] + step * np.array([math.cos(poses[r, 2]), math.sin(poses[r, 2])])
    d = np.hypot(*(poses[:, :2] - ahead).T)
    d[r] = np.inf
    o = int(np.argmin(d))
    return o if d[o] < 2 * planner._radius_m + 1e-9 else -1


def give_way(planner: ActionPlanner, r: int, cells: np.ndarray, blocked_by: np.ndarray) -> bool:
    """Robot ``r`` is blocked by a team-mate and finds no way round it. If the team-mate has no goal,
    it moves to the nearest cell off ``r``'s way; if both block each other, the one of higher
    index moves off the other's way (its path ahead and its footprint), waits there while the
    other passes, then goes on to its goal. True if robot ``r`` itself now has a path to drive."""
    o = _blocker(planner, r)
    if o < 0:
        return False
    if planner.goals[o, 0] < 0:
        spot = spot_off_the_way(planner, o, r, cells)
        if spot is None:
            return False
        # the idle robot drives to its spot as to a goal (arrives, stays) until its next goal
        planner.goals[o] = spot
        planner.tolerances_m[o] = planner._cell_m
        planner.unreachable[o] = planner.reached[o] = planner.settled[o] = False
        planner._state[o, STUCK] = planner._state[o, WAITS] = 0
        planner.make_way(o, r)
        return False
    if r < o or blocked_by[o] != ROBOT:
        return False
    spot = spot_off_the_way(planner, r, o, cells)
    if spot is None:
        return False
    planner._yield_cell[r] = spot
    planner._yield_steps[r] = 0
    planner.make_way(r, o)
    return True


class Spot(NamedTuple):
    """A cell off another robot's way and the path there (:func:`find_spot`)."""

    cell: np.ndarray
    """(2,) the cell (global)."""
    path: np.ndarray
    """(N, 2) global cells from the mover's cell to the spot."""
    box: Box
    passable: np.ndarray
    """The planning grid of ``box`` the path was planned on."""


def find_spot(
    planner: ActionPlanner,
    mover: int,
    passer: int,
    cells: np.ndarray,
    margin_cells: int | None = None,
    moving: Sequence[int] = (),
    taken: Sequence[np.ndarray] = (),
) -> Spot | None:
    """The nearest cell within ``margin_cells`` (default twice ``local_margin_m``) of ``mover`` off
    ``passer``'s way (clear of its footprint, its next move and the footprints along its path
    ahead, with a cell of room between the footprints), and ``mover``'s path there round the other
    robots' footprints (but those of the robots in ``moving``, which move off the way too, and round
    the footprints of robots standing on the
    cells in ``taken``, spots already given to others, which the spot keeps clear of too); None if
    there is none."""
    mapper = planner.world.mapper
    assert mapper is not None
    h, w = mapper.shape
    m = 2 * planner._local_margin if margin_cells is None else int(margin_cells)
    here = cells[mover]
    box = Box(max(here[0] - m, 0), min(here[0] + m + 1, h), max(here[1] - m, 0), min(here[1] + m + 1, w))
    passable = planning_grid(planner, box, cells)
    keep = [o for o in range(len(cells)) if o == mover or o not in moving]  # the others move away too
    block_robots(passable, box.y0, box.x0, cells[keep], keep.index(mover), planner._robot_offsets)
    if len(taken):  # the spots given to others, with a cell of room round their footprints
        standing = np.concatenate([here[None], np.asarray(taken, dtype=np.int64).reshape(-1, 2)])
        block_robots(passable, box.y0, box.x0, standing, 0, planner._spacing_offsets)
    keep_off = np.zeros_like(passable)
    # the passer's next move (a footprint and a step round it) and the footprints along its path ahead
    reach = disc_offsets((2 * planner._radius_m + planner.world.config.robot.forward_m) / planner._cell_m)
    way = [(cells[passer][None], reach)]
    length, progress = int(planner._state[passer, LENGTH]), int(planner._state[passer, PROGRESS])
    if length:
        way.append((planner._paths[passer, progress : min(length, progress + 2 * m)], planner._spacing_offsets))
    if len(taken):
        way.append((np.asarray(taken).reshape(-1, 2), planner._spacing_offsets))
    for points, disc in way:
        for y, x in points:
            ys, xs = y + disc[:, 0] - box.y0, x + disc[:, 1] - box.x0
            inside = (ys >= 0) & (ys < passable.shape[0]) & (xs >= 0) & (xs < passable.shape[1])
            keep_off[ys[inside], xs[inside]] = True
    field = distance_field(passable, here - box.origin, planner._cell_m)
    spots = np.isfinite(field) & ~keep_off
    if not spots.any():
        return None
    y, x = np.unravel_index(int(np.argmin(np.where(spots, field, np.inf))), field.shape)
    back = descend(field, int(y), int(x), field.size)
    if len(back) == 0:
        return None
    return Spot(np.array([int(y) + box.y0, int(x) + box.x0]), back[::-1] + box.origin, box, passable)


def take_spot(planner: ActionPlanner, mover: int, spot: Spot) -> np.ndarray:
    """Make the path to ``spot`` ``mover``'s path; returns the spot's cell."""
    store_path(planner, mover, spot.path, spot.box, spot.passable, planner._version() + 1)
    return spot.cell


def spot_off_the_way(planner: ActionPlanner, mover: int, passer: int, cells: np.ndarray) -> np.ndarray | None:
    """Plan ``mover``'s path to the nearest cell (within twice ``local_margin_m``) off ``passer``'s
    way (:func:`find_spot`). Stores the path as ``mover``'s; returns the cell, or None if there is none."""
    spot = find_spot(planner, mover, passer, cells)
    return None if spot is None else take_spot(planner, mover, spot)


def continue_giving_way(planner: ActionPlanner, r: int, cells: np.ndarray, actions: np.ndarray) -> None:
    """Robot ``r`` gives way: it drives to its spot (the step kernel follows the stored path) and
    stays there; ``give_way_steps`` steps after it began (or once it has no goal) it re-plans to its
    goal."""
    planner._yield_steps[r] += 1
    arrived = np.abs(cells[r] - planner._yield_cell[r]).max() <= 1
    if arrived or planner._need[r] != 0:
        actions[r] = STAY
        planner._state[r, LAST] = STAY
        planner._need[r] = 0
    if planner._yield_steps[r] > planner.config.give_way_steps or planner.goals[r, 0] < 0:
        planner._yield_cell[r] = -1
        planner._state[r, LENGTH] = 0  # re-plan to the goal on the next step
        planner._state[r, WAITS] = 0
