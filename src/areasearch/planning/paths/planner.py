"""The action planner: the step that drives every robot, and the parts it calls.

:class:`ActionPlanner` builds the read-only :class:`~areasearch.planning.paths.context.PlannerContext` and the
robots' :class:`~areasearch.planning.paths.context.Goals`, and one object per part, each holding its own
state: the :class:`~areasearch.planning.paths.follow.Follower` (paths, progress, re-plans), the
:class:`.bumps.BumpMemory` (the collision map), :class:`.give_way.GiveWay`,
:class:`~areasearch.planning.paths.jams.Jams` and :class:`~areasearch.planning.paths.primitives.Primitives`. Each step
it calls them in turn: the jam tracker, the step kernel of the follower (which brings the collision
map up to date and follows the paths), then for the robots that need Python the giving way and the
re-plans, then the primitive search, then the holding of FORWARDs for team-mates.
"""

from __future__ import annotations

import numpy as np

from ...config import PathConfig
from ...sim.world import World
from ..candidates import Routes
from ..grid import Box
from .bumps import BumpMemory
from .context import Goals, PlannerContext
from .follow import Follower
from .give_way import GiveWay
from .jams import Jams
from .primitives import Primitives
from .state import ROBOT

_NO_CELLS = np.zeros((0, 2), dtype=np.int64)


class ActionPlanner:
    """Drives every robot of a :class:`World` towards its long-term goal, one primitive action a step.

    Call :meth:`set_goals` at each decision, then :meth:`act` every step.
    """

    def __init__(self, config: PathConfig, world: World) -> None:
        self.config = config
        self.world = world
        self.context = PlannerContext.build(config, world)
        n = self.context.num_robots
        self._goals = Goals(n, config.goal_tolerance_m)
        self.bump_memory = BumpMemory(world.scene.shape, n, config.bump_log_per_robot)  # type: ignore[union-attr]
        self.follower = Follower(self.context, self._goals, self.bump_memory)
        self.give_way = GiveWay(self.context, self._goals, self.follower)
        self.jams = Jams(self.context, self._goals, self.follower, self.give_way)
        self.primitives = Primitives(self.context, self._goals, self.follower, self.give_way)

    # ------------------------------------------------------------------ public state
    @property
    def goals(self) -> np.ndarray:
        """(R, 2) the robots' goal cells; a row of -1: no goal."""
        return self._goals.cells

    @property
    def tolerances_m(self) -> np.ndarray:
        """(R,) how close to its goal counts as arrived, per robot."""
        return self._goals.tolerances_m

    @property
    def approach_xy(self) -> np.ndarray:
        """(R, 2) map-frame point each robot must drive its centre over to arrive (NaN: none); see
        :meth:`set_goals`."""
        return self._goals.approach_xy

    @property
    def unreachable(self) -> np.ndarray:
        """(R,) bool: no path to the goal (the caller gives the robot another)."""
        return self._goals.unreachable

    @property
    def reached(self) -> np.ndarray:
        """(R,) bool: within the arrival distance of the goal."""
        return self._goals.reached

    @property
    def settled(self) -> np.ndarray:
        """(R,) bool: arrived and looked at what there was to see around the goal."""
        return self._goals.settled

    @property
    def walled_in(self) -> list[tuple[Box, np.ndarray] | None]:
        """Per robot, after a re-plan that found it walled in (obstacles and bump marks all round):
        the window and the (h, w) mask of the cells it can still reach; else None."""
        return self.follower.walled_in

    @property
    def replans(self) -> int:
        """Re-plans since the planner was made."""
        return self.follower.replans

    @property
    def held(self) -> np.ndarray:
        """(R,) bool: the robots whose FORWARD of the last :meth:`act` was replaced by STAY because it
        would have run into a team-mate (:func:`~areasearch.planning.paths.jams.hold_kernel`), or that wait for
        team-mates before a narrow way in (:attr:`waiting`)."""
        return self.jams.held

    @property
    def jams_resolved(self) -> int:
        """Robots sent to back off the way of another in a jam (:meth:`.jams.Jams.resolve`)."""
        return self.jams.resolved

    @property
    def waiting(self) -> np.ndarray:
        """(R,) bool: the robots a primitive search of the last :meth:`act` found a way in for only
        without the team-mates (they wait for them, counted as held)."""
        return self.primitives.waiting

    @property
    def bumps(self) -> np.ndarray:
        """(H, W) bool: the collision map, cells a bump marked in the last ``bump_memory_steps`` steps."""
        return self.bump_memory.mask

    def inflated_obstacles(self) -> np.ndarray:
        """(H, W) bool: the mapped obstacles inflated by the footprint, brought up to date now
        (:class:`~areasearch.planning.grid.InflatedObstacles`); read-only for callers."""
        return self.context.inflated_obstacles()

    @property
    def paths(self) -> list[np.ndarray | None]:
        """Each robot's current path, (N, 2) cells from where it was planned to the goal, or None."""
        return self.follower.paths()

    @property
    def progress(self) -> np.ndarray:
        """(R,) index of the path cell nearest each robot."""
        return self.follower.progress()

    # ------------------------------------------------------------------ decisions and steps
    def set_goals(
        self,
        goals: np.ndarray,
        tolerances_m: np.ndarray | None = None,
        routes: Routes | None = None,
        approach_xy: np.ndarray | None = None,
    ) -> None:
        """New long-term goals, (R, 2) cells; a row of -1 means "no goal" (the robot stays).

        ``tolerances_m`` (R,): how close counts as arrived, per robot (default ``goal_tolerance_m``;
        a target goal needs the robot within the cover radius of the target itself). ``routes``: the
        robots' distance fields of this decision (``Candidates.routes``, computed on the map as it is
        now), from which each robot's first path is read instead of re-planned. ``approach_xy`` (R, 2):
        per robot, a map-frame point (x, y) it must drive its centre over to arrive, NaN for none
        (a target under the ``paper`` protocol): a robot with one arrives only when a move of its
        sweeps its centre within the cover radius of it, and within ``primitive_search_m`` of it
        plans its last moves with :func:`~areasearch.planning.paths.primitive_search` to do so."""
        goals = np.asarray(goals, dtype=np.int64).reshape(-1, 2)
        approach = (
            np.full((len(goals), 2), np.nan)
            if approach_xy is None
            else np.asarray(approach_xy, dtype=np.float64).reshape(-1, 2)
        )
        state = self._goals
        state.tolerances_m = (
            np.full(len(goals), self.config.goal_tolerance_m)
            if tolerances_m is None
            else np.asarray(tolerances_m, dtype=np.float64).reshape(-1)
        )
        for r in range(len(goals)):
            if not np.array_equal(approach[r], state.approach_xy[r], equal_nan=True):
                self.primitives.new_approach(r)  # a new point to drive over (two targets may share a goal cell)
            if not np.array_equal(goals[r], state.cells[r]):
                self.follower.forget(r)
                state.unreachable[r] = state.reached[r] = state.settled[r] = False
                self.give_way.stop(r)
                self.primitives.new_goal(r)
                if routes is not None and goals[r, 0] >= 0:
                    self.follower.route(r, goals[r], routes)
        state.cells = goals.copy()
        state.approach_xy = approach.copy()

    def move_approach(self, r: int, approach_xy: np.ndarray) -> None:
        """Robot ``r``'s point to drive over moved to ``approach_xy`` (x, y; its target was seen again):
        it has not arrived until it drives over the new point."""
        state = self._goals
        state.approach_xy[r] = approach_xy
        state.reached[r] = state.settled[r] = False
        self.primitives.new_approach(r)

    def act(self, blocked_by: np.ndarray) -> np.ndarray:
        """(R,) actions for this step; ``blocked_by`` is the last step's ``StepResult.blocked_by``."""
        n = len(self._goals)
        self.bump_memory.make_room(n)
        actions = np.empty(n, dtype=np.int64)
        if self.jams.held.any():  # a FORWARD held for a team-mate counts as one the team-mate blocked
            blocked_by = np.where(self.jams.held, ROBOT, blocked_by).astype(blocked_by.dtype)
        self.jams.track(blocked_by)
        pending = self.follower.step(blocked_by, self.primitives.arrival_tolerances(), actions)
        self._in_python(pending, blocked_by, actions)
        if self.config.primitive_search_m > 0:
            self.primitives.step(actions, blocked_by)
        if n > 1:
            self.jams.hold(actions, self.primitives.waiting)
        return actions

    def _in_python(self, pending: int, blocked_by: np.ndarray, actions: np.ndarray) -> None:
        """The robots giving way, then those the step kernel left to Python: a detour that did not
        help makes one of two robots give way; else a re-plan (a detour, or to the goal)."""
        world = self.world
        scene = world.scene
        assert scene is not None
        giving_way = self.give_way.robots()
        cells = scene.world_to_cell(world.believed_poses[:, :2]) if pending or len(giving_way) else _NO_CELLS
        for r in giving_way:
            self.give_way.carry_on(int(r), cells, actions)
        if not pending:
            return
        stalled_after = self.config.robot_wait_steps + self.config.detour_every_steps
        for r, detour in self.follower.pending():
            if self.give_way.active(r):
                continue  # giving way: no re-plan towards the goal yet
            # a detour that did not help (still blocked detour_every_steps later): one of the two gives way
            stalled = detour and self.follower.waits[r] > stalled_after
            if (stalled and self.give_way.blocked(r, cells, blocked_by)) or self.follower.replan(
                r, cells, avoid_robots=detour
            ):
                actions[r] = self.follower.drive(r)
            elif not detour:
                self._goals.unreachable[r] = True

    def make_way(self, mover: int, passer: int) -> None:
        """Note that ``mover`` makes way for ``passer`` (gives way, backs off): for the next
        ``give_way_steps`` steps ``passer``'s blocked tries do not make its goal unreachable."""
        self.give_way.make_way(mover, passer)
