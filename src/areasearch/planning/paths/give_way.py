"""Giving way (not in the paper): two robots that need one narrow passage in opposite ways.

A robot blocked by a team-mate waits, then seeks a detour round the team-mates (the step kernel of
:mod:`~areasearch.planning.paths.follow` asks for one every ``detour_every_steps`` blocked tries). When a
detour has not helped ``detour_every_steps`` steps later, :meth:`GiveWay.blocked` makes one of the two move
off the other's way: the team-mate if it has no goal (it drives to the nearest cell off the other's
way as to a goal, :meth:`GiveWay.find_spot`); if both block each other, the one of higher index,
which drives to such a spot, waits there and after ``give_way_steps`` steps goes on to its own goal
(:meth:`GiveWay.carry_on`). Without it, two robots facing each other in a corridor could block
each other for the rest of an episode.

:class:`GiveWay` holds the robots giving way (their spots and how long they have waited) and who
makes way for whom (:meth:`GiveWay.make_way`), which the jam tracker of
:mod:`~areasearch.planning.paths.jams` reads too.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ..geodesic import distance_field
from ..grid import Box, disc_offsets
from .context import Goals, PlannerContext
from .follow import Follower
from .planning import block_robots, descend
from .state import ROBOT, STAY


class Spot(NamedTuple):
    """A cell off another robot's way and the path there (:meth:`GiveWay.find_spot`)."""

    cell: np.ndarray
    """(2,) the cell (global)."""
    path: np.ndarray
    """(N, 2) global cells from the mover's cell to the spot."""
    box: Box
    passable: np.ndarray
    """The planning grid of ``box`` the path was planned on."""


class GiveWay:
    """The robots giving way: where each waits and for how long it has; and who makes way for whom."""

    def __init__(self, context: PlannerContext, goals: Goals, follower: Follower) -> None:
        n = context.num_robots
        self._context, self._goals, self._follower = context, goals, follower
        self._yield_cell = np.full((n, 2), -1, dtype=np.int64)  # where a robot giving way waits
        self._yield_steps = np.zeros(n, dtype=np.int64)  # steps since it began to give way
        self.making_way = np.zeros(n, dtype=np.int64)
        """(R,) steps left while a robot makes way for another (the jam tracker counts them down)."""
        self.making_way_for = np.full(n, -1, dtype=np.int64)
        """(R,) ... for that robot (-1: none)."""

    def active(self, r: int) -> bool:
        """Robot ``r`` gives way (drives to its spot or waits there)."""
        return bool(self._yield_cell[r, 0] >= 0)

    def robots(self) -> np.ndarray:
        """The robots giving way."""
        return np.flatnonzero(self._yield_cell[:, 0] >= 0)

    def spot(self, r: int) -> np.ndarray:
        """(2,) the cell where robot ``r`` gives way ((-1, -1): none)."""
        return self._yield_cell[r].copy()

    def steps(self, r: int) -> int:
        """Steps since robot ``r`` began to give way."""
        return int(self._yield_steps[r])

    def stop(self, r: int) -> None:
        """Robot ``r`` no longer gives way (a new goal)."""
        self._yield_cell[r] = -1

    def wait_at(self, r: int, cell: np.ndarray) -> None:
        """Robot ``r`` gives way at ``cell`` from now (its path there stored)."""
        self._yield_cell[r] = cell
        self._yield_steps[r] = 0

    def make_way(self, mover: int, passer: int) -> None:
        """Note that ``mover`` makes way for ``passer`` (gives way, backs off): for the next
        ``give_way_steps`` steps ``passer``'s blocked tries do not make its goal unreachable."""
        self.making_way[mover] = self._context.config.give_way_steps
        self.making_way_for[mover] = passer

    def blocker(self, r: int) -> int:
        """The team-mate whose footprint a FORWARD of robot ``r`` would overlap (the nearest one), or -1."""
        world = self._context.world
        poses = world.believed_poses
        step = world.config.robot.forward_m
        ahead = poses[r, :2] + step * np.array([math.cos(poses[r, 2]), math.sin(poses[r, 2])])
        d = np.hypot(*(poses[:, :2] - ahead).T)
        d[r] = np.inf
        o = int(np.argmin(d))
        return o if d[o] < 2 * self._context.radius_m + 1e-9 else -1

    def blocked(self, r: int, cells: np.ndarray, blocked_by: np.ndarray) -> bool:
        """Robot ``r`` is blocked by a team-mate and finds no way round it. If the team-mate has no goal,
        it moves to the nearest cell off ``r``'s way; if both block each other, the one of higher
        index moves off the other's way (its path ahead and its footprint), waits there while the
        other passes, then goes on to its goal. True if robot ``r`` itself now has a path to drive."""
        o = self.blocker(r)
        if o < 0:
            return False
        goals = self._goals
        if goals.cells[o, 0] < 0:
            spot = self.spot_off_the_way(o, r, cells)
            if spot is None:
                return False
            # the idle robot drives to its spot as to a goal (arrives, stays) until its next goal
            goals.send(o, spot, self._context.cell_m)
            self._follower.reset_tries(o)
            self.make_way(o, r)
            return False
        if r < o or blocked_by[o] != ROBOT:
            return False
        spot = self.spot_off_the_way(r, o, cells)
        if spot is None:
            return False
        self.wait_at(r, spot)
        self.make_way(r, o)
        return True

    def find_spot(
        self,
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
        the footprints of robots standing on the cells in ``taken``, spots already given to others,
        which the spot keeps clear of too); None if there is none."""
        context = self._context
        h, w = context.map_of(mover).shape
        m = 2 * context.local_margin if margin_cells is None else int(margin_cells)
        here = cells[mover]
        box = Box(max(here[0] - m, 0), min(here[0] + m + 1, h), max(here[1] - m, 0), min(here[1] + m + 1, w))
        passable = self._follower.planning_grid(box, cells, mover)
        keep = [o for o in range(len(cells)) if o == mover or o not in moving]  # the others move away too
        block_robots(passable, box.y0, box.x0, cells[keep], keep.index(mover), context.robot_offsets)
        if len(taken):  # the spots given to others, with a cell of room round their footprints
            standing = np.concatenate([here[None], np.asarray(taken, dtype=np.int64).reshape(-1, 2)])
            block_robots(passable, box.y0, box.x0, standing, 0, context.spacing_offsets)
        keep_off = np.zeros_like(passable)
        # the passer's next move (a footprint and a step round it) and the footprints along its path ahead
        reach = disc_offsets((2 * context.radius_m + context.world.config.robot.forward_m) / context.cell_m)
        way = [(cells[passer][None], reach)]
        if self._follower.has_path(passer):
            way.append((self._follower.path_ahead(passer, 2 * m), context.spacing_offsets))
        if len(taken):
            way.append((np.asarray(taken).reshape(-1, 2), context.spacing_offsets))
        for points, disc in way:
            for y, x in points:
                ys, xs = y + disc[:, 0] - box.y0, x + disc[:, 1] - box.x0
                inside = (ys >= 0) & (ys < passable.shape[0]) & (xs >= 0) & (xs < passable.shape[1])
                keep_off[ys[inside], xs[inside]] = True
        field = distance_field(passable, here - box.origin, context.cell_m)
        spots = np.isfinite(field) & ~keep_off
        if not spots.any():
            return None
        y, x = np.unravel_index(int(np.argmin(np.where(spots, field, np.inf))), field.shape)
        back = descend(field, int(y), int(x), field.size)
        if len(back) == 0:
            return None
        return Spot(np.array([int(y) + box.y0, int(x) + box.x0]), back[::-1] + box.origin, box, passable)

    def take_spot(self, mover: int, spot: Spot) -> np.ndarray:
        """Make the path to ``spot`` ``mover``'s path; returns the spot's cell."""
        self._follower.store_path(mover, spot.path, spot.box, spot.passable, self._context.version() + 1)
        return spot.cell

    def spot_off_the_way(self, mover: int, passer: int, cells: np.ndarray) -> np.ndarray | None:
        """Plan ``mover``'s path to the nearest cell (within twice ``local_margin_m``) off ``passer``'s
        way (:meth:`find_spot`). Stores the path as ``mover``'s; returns the cell, or None if there is none."""
        spot = self.find_spot(mover, passer, cells)
        return None if spot is None else self.take_spot(mover, spot)

    def carry_on(self, r: int, cells: np.ndarray, actions: np.ndarray) -> None:
        """Robot ``r`` gives way: it drives to its spot (the step kernel follows the stored path) and
        stays there; ``give_way_steps`` steps after it began (or once it has no goal) it re-plans to its
        goal."""
        self._yield_steps[r] += 1
        arrived = np.abs(cells[r] - self._yield_cell[r]).max() <= 1
        if arrived or self._follower.needs(r):
            self._follower.take(r, STAY, actions)
        if self._yield_steps[r] > self._context.config.give_way_steps or self._goals.cells[r, 0] < 0:
            self._yield_cell[r] = -1
            self._follower.drop_path(r)  # re-plan to the goal on the next step
