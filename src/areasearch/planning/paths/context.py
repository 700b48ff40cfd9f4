"""What every part of the action planner shares: the read-only :class:`PlannerContext` (settings,
world, footprint discs, the step kernels' parameter arrays) and the robots' :class:`Goals`.

Each part (:class:`~areasearch.planning.paths.follow.Follower`, :class:`~areasearch.planning.paths.bumps.BumpMemory`,
:class:`~areasearch.planning.paths.give_way.GiveWay`, :class:`~areasearch.planning.paths.jams.Jams`,
:class:`~areasearch.planning.paths.primitives.Primitives`) holds its own state; the goals are the one state
several parts change (a robot sent off another's way drives to its spot as to a goal).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ...config import PathConfig
from ...sim.footprint import footprint_offsets
from ...sim.mapper import Mapper
from ...sim.world import World
from ..grid import InflatedObstacles, disc_offsets


@dataclass(frozen=True)
class PlannerContext:
    """The settings and the world of one action planner, and what follows from them once
    (:meth:`build`). Read-only for the parts; the world and the inflated obstacles change as the
    world steps, their references do not."""

    config: PathConfig
    world: World
    num_robots: int
    cell_m: float
    radius_m: float
    offsets: np.ndarray
    """Footprint offsets: where an obstacle cell blocks a robot centre."""
    inflated: InflatedObstacles
    robot_offsets: np.ndarray
    """Robots closer than two radii overlap."""
    spacing_offsets: np.ndarray
    """... and a cell of room between them."""
    local_margin: int
    """``local_margin_m`` in cells."""
    window_margin: int
    """``unknown_margin_m`` in cells, plus one."""
    fparams: np.ndarray
    """The step kernels' float parameters, slots as in :mod:`~areasearch.planning.paths.state` (``F_*``)."""
    iparams: np.ndarray
    """The step kernels' integer parameters (``I_*``)."""
    move_params: tuple[float, float, float, float, float, float, float]
    """Map origin x, y, cell size, forward step, turn step, squared least robot separation and radius
    (metres, radians): the world's motion rule, as the primitive search reads it."""
    cover_m: float
    team_map_of: np.ndarray
    """(R,) zeros: every robot reads map 0 of the step kernel's stack (the team's map, :meth:`map_stacks`)."""
    robot_map_of: np.ndarray
    """(R,) 0 .. R-1: robot ``r`` reads map ``r`` of the stacks (each robot's own, limited communication)."""
    robot_inflated: dict[int, InflatedObstacles] = field(default_factory=dict)
    """Each robot's own :class:`InflatedObstacles`, made on first use (limited communication only)."""

    @classmethod
    def build(cls, config: PathConfig, world: World) -> PlannerContext:
        """The context of a planner with ``config`` for ``world`` (reset, so that it has a scene)."""
        scene = world.scene
        assert scene is not None
        cell_m = scene.cell_m
        robot = world.config.robot
        radius = robot.radius_m
        fparams = np.array(
            [
                scene.origin_xy[0],
                scene.origin_xy[1],
                cell_m,
                robot.turn_rad / 2 + 1e-6,  # FORWARD within half a turn step
                math.radians(world.config.camera.hfov_deg) / 4,  # looking at a frontier: within half the view
                cell_m / 2,
                robot.forward_m,
                config.min_aim_m,
            ]
        )
        iparams = np.array(
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
        move_params = (
            scene.origin_xy[0],
            scene.origin_xy[1],
            cell_m,
            robot.forward_m,
            robot.turn_rad,
            (2 * radius) ** 2,
            radius,
        )
        return cls(
            config=config,
            world=world,
            num_robots=world.config.num_robots,
            cell_m=cell_m,
            radius_m=radius,
            offsets=footprint_offsets(cell_m, radius),
            inflated=InflatedObstacles(scene.shape, cell_m, radius),
            robot_offsets=disc_offsets(2 * radius / cell_m),
            spacing_offsets=disc_offsets(2 * radius / cell_m + 1),
            local_margin=round(config.local_margin_m / cell_m),
            window_margin=int(math.floor(config.unknown_margin_m / cell_m + 1e-9)) + 1,
            fparams=fparams,
            iparams=iparams,
            move_params=move_params,
            cover_m=world.config.cover_radius_m,
            team_map_of=np.zeros(world.config.num_robots, dtype=np.int64),
            robot_map_of=np.arange(world.config.num_robots, dtype=np.int64),
        )

    def map_of(self, robot: int | None = None) -> Mapper:
        """The map robot ``robot`` plans on: its own, merged with its group's, under limited communication
        (:attr:`~areasearch.sim.world.World.robot_maps`); the team's (:attr:`World.mapper`) otherwise or
        for None."""
        mapper = self.world.mapper if robot is None else self.world.robot_maps[robot]
        assert mapper is not None
        return mapper

    def map_stacks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``explored``, ``occupied``, ``occupied_at`` as (M, H, W) stacks and the (R,) map of each robot, as
        the step kernel reads them: the team's map alone (views, no copy), or each robot's own map."""
        if self.world.knowledge is None:
            mapper = self.map_of()
            return mapper.explored[None], mapper.occupied[None], mapper.occupied_at[None], self.team_map_of
        explored, occupied, occupied_at = self.world.knowledge.planes
        return explored, occupied, occupied_at, self.robot_map_of

    def version(self) -> int:
        """Map version of the current map: twice the mapper's integrations (obstacles it marks carry
        ``2 * occupied_at``); bump marks of a step carry one more, paths planned carry the version
        of the map they were planned on (decision routes: before this step's bumps, re-plans: after)."""
        mapper = self.world.mapper
        assert mapper is not None
        return 2 * mapper.integrations

    def inflated_obstacles(self, robot: int | None = None) -> np.ndarray:
        """(H, W) bool: the obstacles of ``robot``'s map (:meth:`map_of`) inflated by the footprint, brought up
        to date now."""
        mapper = self.map_of(robot)
        if mapper is self.world.mapper:
            return self.inflated.update(mapper.occupied)
        assert robot is not None
        if robot not in self.robot_inflated:
            self.robot_inflated[robot] = InflatedObstacles(mapper.shape, self.cell_m, self.radius_m)
        return self.robot_inflated[robot].update(mapper.occupied)


class Goals:
    """The robots' long-term goals and how each stands towards its goal."""

    def __init__(self, num_robots: int, tolerance_m: float) -> None:
        self.cells = np.full((num_robots, 2), -1, dtype=np.int64)
        """(R, 2) goal cells; a row of -1: no goal."""
        self.tolerances_m = np.full(num_robots, tolerance_m)
        """(R,) how close counts as arrived."""
        self.approach_xy = np.full((num_robots, 2), np.nan)
        """(R, 2) map-frame point each robot must drive its centre over to arrive (NaN: none)."""
        self.unreachable = np.zeros(num_robots, dtype=bool)
        self.reached = np.zeros(num_robots, dtype=bool)
        self.settled = np.zeros(num_robots, dtype=bool)
        """Arrived and looked at what there was to see around the goal."""

    def __len__(self) -> int:
        return len(self.cells)

    def has_goal(self, r: int) -> bool:
        """Robot ``r`` has a goal it has neither reached nor given up."""
        return bool(self.cells[r, 0] >= 0 and not self.unreachable[r] and not self.reached[r])

    def send(self, r: int, cell: np.ndarray, tolerance_m: float) -> None:
        """Robot ``r`` drives to ``cell`` as to a goal (a spot off another's way), not yet reached."""
        self.cells[r] = cell
        self.tolerances_m[r] = tolerance_m
        self.unreachable[r] = self.reached[r] = self.settled[r] = False
