"""The action planner: the per-robot state of path following and the step that drives every robot.

:class:`ActionPlanner` holds the state (goals, paths, the bump memory, plans of primitive moves, the
robots giving way) and calls the parts each step: the step kernel of :mod:`~areasearch.paths.follow`
(which brings :mod:`~areasearch.paths.bumps` up to date and follows the paths), then for the robots
that need Python :mod:`~areasearch.paths.give_way` and the re-plans of
:mod:`~areasearch.paths.follow`, then :mod:`~areasearch.paths.primitives`. The parts read and write
the planner's arrays in place: they are its own code, split by concern.
"""

from __future__ import annotations

import math

import numpy as np

from ..candidates import Routes
from ..config import PathConfig
from ..footprint import footprint_offsets
from ..geodesic import Box, InflatedObstacles, disc_offsets
from ..world import World
from .bumps import BumpMemory
from .follow import act_kernel, drive, replan, route
from .give_way import continue_giving_way, give_way
from .jams import hold_kernel, resolve_jams, track_kernel
from .primitives import MAX_MOVES, arrival_tolerances, primitive_moves
from .state import DETOUR, LAST, LENGTH, PROGRESS, ROBOT, STAY, STUCK, WAITS


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
        self._offsets = footprint_offsets(cell_m, radius)  # where an obstacle cell blocks a centre
        self._inflated = InflatedObstacles(scene.shape, cell_m, radius)
        self._robot_offsets = disc_offsets(2 * radius / cell_m)  # robots closer than two radii overlap
        self._spacing_offsets = disc_offsets(2 * radius / cell_m + 1)  # ... and a cell of room between them
        self._local_margin = round(config.local_margin_m / cell_m)
        self._window_margin = int(math.floor(config.unknown_margin_m / cell_m + 1e-9)) + 1
        # the step kernel's parameters, slots as in .state (F_*, I_*)
        self._fparams = np.array(
            [
                scene.origin_xy[0],
                scene.origin_xy[1],
                cell_m,
                world.config.robot.turn_rad / 2 + 1e-6,  # FORWARD within half a turn step
                math.radians(world.config.camera.hfov_deg) / 4,  # looking at a frontier: within half the view
                cell_m / 2,
                world.config.robot.forward_m,
                config.min_aim_m,
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
                config.detour_every_steps,
                config.progress_window_cells,
            ],
            dtype=np.int64,
        )
        # following a path (.follow)
        self._state = np.zeros((n, 6), dtype=np.int64)  # columns as in .state (PROGRESS ... LAST)
        self._state[:, LAST] = STAY
        self._paths = np.zeros((n, config.path_buffer_cells, 2), dtype=np.int64)  # grows for longer paths
        self._los = np.zeros((n, *scene.shape), dtype=bool)  # each robot's planning grid (its window)
        self._los_box = np.zeros((n, 4), dtype=np.int64)  # (y0, y1, x0, x1) of that window
        self._need = np.zeros(n, dtype=np.int8)  # REPLAN / DETOUR: what the step kernel left to Python
        self._no_cells = np.zeros((0, 2), dtype=np.int64)
        # the collision map (.bumps)
        self._bump_memory = BumpMemory(scene.shape, n, config.bump_log_per_robot)
        # giving way (.give_way)
        self._yield_cell = np.full((n, 2), -1, dtype=np.int64)  # where a robot giving way waits
        self._yield_steps = np.zeros(n, dtype=np.int64)  # steps since it began to give way
        # primitive search (.primitives)
        robot = world.config.robot
        self._move_params = (
            scene.origin_xy[0],
            scene.origin_xy[1],
            cell_m,
            robot.forward_m,
            robot.turn_rad,
            (2 * radius) ** 2,
            radius,
        )
        self._bump_ahead = np.zeros(n, dtype=np.bool_)
        self._moves = np.zeros((n, MAX_MOVES), dtype=np.int64)  # primitive-search plans, per robot
        self._moves_len = np.zeros(n, dtype=np.int64)  # 0: none
        self._moves_at = np.zeros(n, dtype=np.int64)  # next action of the plan
        self._moves_failed = np.full(n, -(10**9), dtype=np.int64)  # step of the last search that found none
        self._narrow_tried = np.full((n, 2), -1, dtype=np.int64)  # cell of the last long search in a narrow way
        self._wait_key = [np.zeros(0)] * n  # poses and goal of the last wait for team-mates (primitives)
        self.approach_xy = np.full((n, 2), np.nan)
        """(R, 2) map-frame point each robot must drive its centre over to arrive (NaN: none); see
        :meth:`set_goals`."""
        self._passed = np.zeros(n, dtype=bool)  # drove over its approach point since its goal was set
        self._cover_m = world.config.cover_radius_m
        self._kernel_tol = self.tolerances_m.copy()  # arrival distances as the step kernel reads them
        # jams (.jams)
        self.held = np.zeros(n, dtype=bool)
        """(R,) bool: the robots whose FORWARD of the last :meth:`act` was replaced by STAY because it
        would have run into a team-mate (:func:`~areasearch.paths.jams.hold_kernel`)."""
        self.jams_resolved = 0
        """Robots sent to back off the way of another in a jam since the reset (:func:`resolve_jams`)."""
        self.waiting = np.zeros(n, dtype=bool)
        """(R,) bool: the robots a primitive search of the last :meth:`act` found a way in for only
        without the team-mates (they wait for them, counted as held)."""
        self._still = np.zeros(n, dtype=np.int64)  # steps since each robot last changed position
        self._making_way = np.zeros(n, dtype=np.int64)  # steps left while a robot makes way for another
        self._making_way_for = np.full(n, -1, dtype=np.int64)  # ... for that robot
        self._last_xy = world.poses[:, :2].copy()
        self._jam_seen: dict[tuple[int, ...], tuple[np.ndarray, int]] = {}
        """Per jam group (robot indices): the poses when it was last resolved and how many times
        running it has been found again with nobody moved since (:func:`~.jams.resolve_jams`)."""

    # ------------------------------------------------------------------ public state
    @property
    def bumps(self) -> np.ndarray:
        """(H, W) bool: the collision map, cells a bump marked in the last ``bump_memory_steps`` steps."""
        return self._bump_memory.mask

    def inflated_obstacles(self) -> np.ndarray:
        """(H, W) bool: the mapped obstacles inflated by the footprint, brought up to date now
        (:class:`~areasearch.geodesic.InflatedObstacles`); read-only for callers."""
        mapper = self.world.mapper
        assert mapper is not None
        return self._inflated.update(mapper.occupied)

    @property
    def paths(self) -> list[np.ndarray | None]:
        """Each robot's current path, (N, 2) cells from where it was planned to the goal, or None."""
        lengths = self._state[:, LENGTH]
        return [self._paths[r, : lengths[r]].copy() if lengths[r] else None for r in range(len(self.goals))]

    @property
    def progress(self) -> np.ndarray:
        """(R,) index of the path cell nearest each robot."""
        return self._state[:, PROGRESS].copy()

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
        plans its last moves with :func:`~areasearch.paths.primitive_search` to do so."""
        goals = np.asarray(goals, dtype=np.int64).reshape(-1, 2)
        approach = (
            np.full((len(goals), 2), np.nan)
            if approach_xy is None
            else np.asarray(approach_xy, dtype=np.float64).reshape(-1, 2)
        )
        self.tolerances_m = (
            np.full(len(goals), self.config.goal_tolerance_m)
            if tolerances_m is None
            else np.asarray(tolerances_m, dtype=np.float64).reshape(-1)
        )
        for r in range(len(goals)):
            if not np.array_equal(approach[r], self.approach_xy[r], equal_nan=True):
                self._passed[r] = False  # a new point to drive over (two targets may share a goal cell)
                self._moves_len[r] = 0
            if not np.array_equal(goals[r], self.goals[r]):
                self._state[r, LENGTH] = 0
                self._state[r, PROGRESS] = 0
                self._state[r, STUCK] = 0
                self._state[r, WAITS] = 0
                self.unreachable[r] = False
                self.reached[r] = False
                self.settled[r] = False
                self.walled_in[r] = None
                self._yield_cell[r] = -1
                self._moves_len[r] = 0
                self._moves_failed[r] = -(10**9)
                self._passed[r] = False
                if routes is not None and goals[r, 0] >= 0:
                    route(self, r, goals[r], routes)
        self.goals = goals.copy()
        self.approach_xy = approach.copy()

    def act(self, blocked_by: np.ndarray) -> np.ndarray:
        """(R,) actions for this step; ``blocked_by`` is the last step's ``StepResult.blocked_by``."""
        world = self.world
        mapper = world.mapper
        assert mapper is not None
        n = len(self.goals)
        memory = self._bump_memory
        memory.make_room(n)
        actions = np.empty(n, dtype=np.int64)
        if self.held.any():  # a FORWARD held for a team-mate counts as one the team-mate blocked
            blocked_by = np.where(self.held, ROBOT, blocked_by).astype(blocked_by.dtype)
        if track_kernel(
            world.poses, self._last_xy, self._still, self._state[:, WAITS], self._making_way, self._making_way_for,
            self.config.robot_wait_limit, self.config.deadlock_steps,
        ):  # fmt: skip
            jam_cells = world.scene.world_to_cell(world.poses[:, :2])  # type: ignore[union-attr]
            self.jams_resolved += resolve_jams(self, blocked_by, jam_cells)
        tolerances = arrival_tolerances(self)
        pending = act_kernel(
            world.poses, blocked_by, self.goals, tolerances, self._paths, self._state,
            self.unreachable, self.reached, self.settled, mapper.explored, mapper.occupied, mapper.occupied_at,
            self._version() + 1, world.metrics.steps, memory.mask, memory.count, memory.at,
            memory.log, memory.ptr, self._offsets, self._los, self._los_box, self._fparams,
            self._iparams, actions, self._need,
        )  # fmt: skip
        scene = world.scene
        assert scene is not None
        giving_way = np.flatnonzero(self._yield_cell[:, 0] >= 0)
        cells = scene.world_to_cell(world.poses[:, :2]) if pending or len(giving_way) else self._no_cells
        for r in giving_way:
            continue_giving_way(self, int(r), cells, actions)
        if pending:
            stalled_after = self.config.robot_wait_steps + self.config.detour_every_steps
            for r in np.flatnonzero(self._need):
                if self._yield_cell[r, 0] >= 0:
                    continue  # giving way: no re-plan towards the goal yet
                detour = self._need[r] == DETOUR
                # a detour that did not help (still blocked detour_every_steps later): one of the two gives way
                stalled = detour and self._state[r, WAITS] > stalled_after
                if (stalled and give_way(self, int(r), cells, blocked_by)) or replan(
                    self, int(r), cells, avoid_robots=detour
                ):
                    actions[r] = drive(
                        int(r), world.poses, self._paths, self._state, self._los, self._los_box,
                        self._fparams, self._iparams,
                    )  # fmt: skip
                elif not detour:
                    self.unreachable[r] = True
        if self.config.primitive_search_m > 0:
            self.waiting[:] = False
            primitive_moves(self, actions, blocked_by)
        if n > 1:
            hold_kernel(world.poses, actions, world.config.robot.forward_m, self._move_params[5], self.held)
            self.held |= self.waiting
        return actions

    def make_way(self, mover: int, passer: int) -> None:
        """Note that ``mover`` makes way for ``passer`` (gives way, backs off): for the next
        ``give_way_steps`` steps ``passer``'s blocked tries do not make its goal unreachable."""
        self._making_way[mover] = self.config.give_way_steps
        self._making_way_for[mover] = passer

    def _version(self) -> int:
        """Map version of the current map: twice the mapper's integrations (obstacles it marks carry
        ``2 * occupied_at``); bump marks of a step carry one more, paths planned carry the version
        of the map they were planned on (decision routes: before this step's bumps, re-plans: after)."""
        mapper = self.world.mapper
        assert mapper is not None
        return 2 * mapper.integrations
