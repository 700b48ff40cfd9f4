"""Pipeline stage "world": robots, targets and metrics in a 2.5D scene (DA-HGNN "Problem Formulation").

One :class:`World` holds a team of ``num_robots`` robots in a :class:`~areasearch.sim.scene.Scene`.
Each :meth:`World.step` takes one primitive action per robot (:class:`Action`), moves the robots,
renders each robot's depth image (:mod:`areasearch.sim.depth`), fuses all images into the shared map
(:mod:`areasearch.sim.mapper`), discovers targets on newly explored cells, covers discovered targets a
robot comes near, and updates the metrics and the paper's reward.

Motion: FORWARD moves ``forward_m`` along the heading; TURN_LEFT / TURN_RIGHT rotate by
``turn_deg``; STAY does nothing. A forward move during which the footprint (a disc of
``robot.radius_m``) would overlap an obstacle cell anywhere along its path (the exact swept disc
against the cell squares, :mod:`areasearch.sim.footprint`), or would overlap another robot on the way
(centres closer than two radii), does not happen and counts as a collision. Robots move one after
another in index order, each seeing the others' updated positions.

Targets: ``targets.count`` targets on distinct free cells, drawn uniformly among the cells a robot
can cover; a target is *discovered* when its cell becomes explored, and *covered*, after it was
discovered, by the rule of the configured protocol (:data:`~areasearch.config.PROTOCOLS`):

* ``paper`` (default): a robot centre passes over the target's cell — the segment it swept during
  the step comes within 0.05 m of the cell centre; targets lie on cells a robot centre can stand on
  (:func:`coverable_cells`);
* ``passby``: a robot centre ends a step within ``cover_radius_m`` (0.3 m) of the target; targets
  lie within :attr:`World.placement_radius_m` (the cover radius less half a forward step) of a cell
  the team can reach.

Metrics (all in :class:`Metrics`): explored fraction = explored reachable floor / reachable floor,
where the reachable floor is the scene's reachable space (:meth:`~areasearch.sim.scene.Scene.reachable_floor`:
the free cells the footprint reaches from the team's region by the collision rule of the moves;
free floor it cannot reach, e.g. behind a doorway narrower than the robot, counts nowhere and is
reported as ``unreachable_m2``); covered fraction = covered / count; Time_E / Time_C = first step at which they reach
``success_fraction`` (the horizon when never, with ``reached_e`` / ``reached_c`` False);
collisions and path length per robot.

Reward (paper eq. of "Policy Optimization"): r_t = a1 (S^e_t - S^e_{t-1}) + a2 (targets newly
covered at t) + a3, with S^e in square metres and the a's of :class:`~areasearch.config.RewardConfig`.

Noise and detection (the ``noise`` and ``detection`` groups of the configuration, all off by default):
with every one off, :meth:`World.step` runs the fused path above and :attr:`World.believed_poses` is
:attr:`World.poses` itself. With any on, it runs the noisy path (:mod:`areasearch.sim.noise`): noisy
moves of the true poses, believed poses that follow by odometry, depth rendered at the true poses and
fused at the believed ones after range noise and dropout, targets detected with a probability per
frame; collisions, coverage and the metrics go by the true poses, the planners read the believed ones.

Communication (the ``comm`` group; ``full`` by default): limited communication runs the noisy path too, and
each robot keeps a map and target knowledge of its own, merged within the groups of robots that can talk
after every step (:mod:`areasearch.sim.knowledge`): :attr:`World.robot_maps`, :attr:`World.comm_groups`,
:attr:`World.heard`. :attr:`World.mapper` is then the union of every robot's frames; the metrics count the
truth (the floor some robot truly saw, the targets truly covered).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numba
import numpy as np

from ..config import WorldConfig
from ..errors import ConfigError
from .comm import CommState
from .depth import camera_tables, render_depth
from .footprint import point_segment_d2, segment_hits
from .knowledge import TeamKnowledge
from .mapper import Mapper
from .noise import Imperfections, TargetState, sense
from .placement import check_start_poses, draw_targets, placement_radius_m, sample_start_poses
from .placement import coverable_cells as coverable_cells  # re-exported: imported from here too
from .placement import sample_targets as sample_targets
from .placement import sample_targets_on as sample_targets_on
from .scene import Scene
from .sensing import sense_kernel

BLOCKED_BY_OBSTACLE = 1
BLOCKED_BY_ROBOT = 2


class Action(IntEnum):
    """Primitive actions of one robot."""

    FORWARD = 0
    TURN_LEFT = 1
    TURN_RIGHT = 2
    STAY = 3


@dataclass
class Metrics:
    """Episode metrics so far (the paper's "Evaluation Metrics")."""

    steps: int = 0
    explored_fraction: float = 0.0
    covered_fraction: float = 0.0
    time_e: int = 0
    """First step with explored_fraction >= success_fraction; the horizon (``max_steps``) if not reached
    (yet): an episode that ends early without reaching it counts as taking the whole horizon."""
    time_c: int = 0
    reached_e: bool = False
    reached_c: bool = False
    explored_m2: float = 0.0
    reachable_m2: float = 0.0
    """Area of the scene's reachable floor (the denominator of ``explored_fraction``), m²."""
    unreachable_m2: float = 0.0
    """Free floor of the map the footprint cannot reach (not part of the scene), m²."""
    covered: int = 0
    discovered: int = 0
    collisions: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """(R,) collisions per robot."""
    path_length_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """(R,) distance driven per robot, metres."""

    @property
    def covered_of_discovered_pct(self) -> float:
        """Covered / discovered targets, percent (100 while none is discovered): what the DA-HGNN
        authors' coverage code reports beside the paper's covered / all."""
        return 100.0 * self.covered / self.discovered if self.discovered else 100.0

    def as_dict(self) -> dict[str, float | int | bool | list[float] | list[int]]:
        return {
            "steps": self.steps,
            "explored_pct": 100.0 * self.explored_fraction,
            "covered_pct": 100.0 * self.covered_fraction,
            "covered_of_discovered_pct": self.covered_of_discovered_pct,
            "time_e": self.time_e,
            "time_c": self.time_c,
            "reached_e": self.reached_e,
            "reached_c": self.reached_c,
            "explored_m2": self.explored_m2,
            "reachable_m2": self.reachable_m2,
            "unreachable_m2": self.unreachable_m2,
            "covered": self.covered,
            "discovered": self.discovered,
            "collisions": [int(c) for c in self.collisions],
            "path_length_m": [float(p) for p in self.path_length_m],
        }


@dataclass(frozen=True)
class StepResult:
    """What one :meth:`World.step` did."""

    reward: float
    new_explored_m2: float
    new_covered: int
    new_discovered: int
    collided: np.ndarray
    """(R,) bool: the robot's move was blocked this step."""
    blocked_by: np.ndarray
    """(R,) int8: what blocked it: 0 nothing, 1 an obstacle (:data:`BLOCKED_BY_OBSTACLE`),
    2 another robot (:data:`BLOCKED_BY_ROBOT`)."""


@numba.njit(cache=True, nogil=True, error_model="numpy")
def wrap_angle(angle: float) -> float:
    """Angle in [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _move_kernel(
    poses: np.ndarray,
    actions: np.ndarray,
    obstacles: np.ndarray,
    cell_m: float,
    origin_x: float,
    origin_y: float,
    forward_m: float,
    turn_rad: float,
    radius_m: float,
    blocked_by: np.ndarray,
    collisions: np.ndarray,
    path_length_m: np.ndarray,
    previous_xy: np.ndarray,
) -> bool:
    """Move the robots in index order, count each robot's collisions and distance driven, keep each
    centre's position before the move in ``previous_xy``; False (and nothing moved) if an action is
    not 0..3. A FORWARD is blocked when the footprint swept along it overlaps an ``obstacles`` cell
    (:func:`~areasearch.sim.footprint.segment_hits`) or a team-mate's footprint (the centre comes
    within two radii of the team-mate's on the way)."""
    n = poses.shape[0]
    for r in range(n):
        if actions[r] < 0 or actions[r] > 3:
            return False
    for r in range(n):
        previous_xy[r, 0] = poses[r, 0]
        previous_xy[r, 1] = poses[r, 1]
    min_sep2 = (2.0 * radius_m) ** 2
    for r in range(n):
        blocked_by[r] = 0
        a = actions[r]
        if a == 1:
            poses[r, 2] = wrap_angle(poses[r, 2] + turn_rad)
        elif a == 2:
            poses[r, 2] = wrap_angle(poses[r, 2] - turn_rad)
        elif a == 0:
            cx = math.cos(poses[r, 2])
            sy = math.sin(poses[r, 2])
            why = 0
            x, y = poses[r, 0], poses[r, 1]
            if segment_hits(
                obstacles, 0, 0, origin_x, origin_y, cell_m, x, y, x + cx * forward_m, y + sy * forward_m, radius_m
            ):
                why = 1
            if why == 0:
                nx = x + cx * forward_m
                ny = y + sy * forward_m
                for o in range(n):
                    if o != r and point_segment_d2(poses[o, 0], poses[o, 1], x, y, nx, ny) < min_sep2:
                        why = 2
                        break
            if why == 0:
                poses[r, 0] += cx * forward_m
                poses[r, 1] += sy * forward_m
                path_length_m[r] += forward_m
            else:
                blocked_by[r] = why
                collisions[r] += 1
    return True


class World:
    """State of one search episode. Call :meth:`reset` before :meth:`step`."""

    def __init__(self, config: WorldConfig | None = None) -> None:
        self.config = (config or WorldConfig()).validate()
        self.scene: Scene | None = None
        self.mapper: Mapper | None = None
        self.noise: Imperfections | None = None
        """The noisy path's state (:mod:`areasearch.sim.noise`), None when every imperfection is off."""
        self.knowledge: TeamKnowledge | None = None
        """Each robot's own knowledge (:mod:`areasearch.sim.knowledge`), None with full communication."""

    # ------------------------------------------------------------------------------- reset
    def reset(self, scene: Scene, rng: np.random.Generator, poses: Any = None) -> None:
        """Start an episode in ``scene``: draw start poses and targets from ``rng``, sense once.

        ``poses`` (R, 3) x, y, yaw (metres, radians, map frame): start the robots there instead of
        drawing their poses (:func:`check_start_poses`: each inside the team's region, no two
        footprints overlapping; ConfigError naming the robot otherwise); the targets are then drawn
        from ``rng`` as they are after drawn poses."""
        cfg = self.config
        self.scene = scene
        radius = cfg.robot.radius_m
        reachable = scene.reachable(radius)
        n = cfg.num_robots
        self._obstacles = ~scene.free  # the footprint rule's obstacle cells (areasearch.sim.footprint)
        if poses is None:
            self.poses = sample_start_poses(scene, reachable, n, radius, rng)
        else:
            self.poses = check_start_poses(scene, reachable, poses, n, radius)
        self.target_cells = draw_targets(scene, reachable, cfg, rng)
        self._imperfect = cfg.imperfect  # the noisy path (sim/noise.py); its generator drawn only then
        self.noise = Imperfections(cfg, scene, np.random.default_rng(rng.integers(2**63))) if self._imperfect else None
        k = len(self.target_cells)
        self.targets_xy = scene.cell_to_world(self.target_cells) if k else np.zeros((0, 2))
        self.target_cells = np.ascontiguousarray(self.target_cells, dtype=np.int64)
        self.target_id = np.full(scene.shape, -1, dtype=np.int64)
        if k:
            self.target_id[self.target_cells[:, 0], self.target_cells[:, 1]] = np.arange(k)
        self.discovered = np.zeros(k, dtype=bool)
        self.covered = np.zeros(k, dtype=bool)
        self.discovered_at = np.full(k, -1, dtype=np.int64)
        self.covered_at = np.full(k, -1, dtype=np.int64)
        self._reset_mapper(scene)
        floor = scene.reachable_floor(radius)
        self._free_flat = floor.ravel()
        self._target_id_flat = self.target_id.ravel()
        self._h_max = float(scene.height_m.max())
        self._free_cells = int(self._free_flat.sum())
        self._cell_area = scene.cell_m**2
        self._counts = np.zeros(3, dtype=np.int64)  # explored free cells, discovered, covered
        self.depth = np.zeros((n, cfg.camera.height_px, cfg.camera.width_px), dtype=np.float32)
        self._sensed = np.full((n, 3), np.nan)  # the pose each robot last sensed from
        self.trajectory = np.zeros((cfg.max_steps + 1, n, 3))
        self.trajectory[0] = self.poses
        self._blocked_by = np.zeros(n, dtype=np.int8)
        self._cell_m, self._origin_x, self._origin_y = scene.cell_m, scene.origin_xy[0], scene.origin_xy[1]
        self._height = scene.height_m
        self._tables = camera_tables(cfg.camera)
        self._cover_r2 = cfg.cover_radius_m**2
        self._swept = cfg.rule.swept
        self.previous_xy = self.poses[:, :2].copy()  # a copy: for one robot the slice is contiguous
        """(R, 2) each robot centre before the last step (the start of the segment it swept)."""
        self._reset_beliefs()
        self.metrics = Metrics(
            collisions=np.zeros(n, dtype=np.int64),
            path_length_m=np.zeros(n),
            reachable_m2=self._free_cells * self._cell_area,
            unreachable_m2=(int(scene.free.sum()) - self._free_cells) * self._cell_area,
        )
        self._sense_noisy() if self._imperfect else self._sense()
        self._update_metrics()

    def _reset_mapper(self, scene: Scene) -> None:
        """An empty map of ``scene``'s grid (the mapper of the last episode, cleared, when the grid is the same)."""
        if self.mapper is None or self.mapper.shape != scene.shape or self.mapper.cell_m != scene.cell_m:
            self.mapper = Mapper(
                scene.shape, scene.cell_m, scene.origin_xy, obstacle_top_m=self.config.robot.height_m,
                occupancy=self.config.mapping,
            )  # fmt: skip
        else:
            self.mapper.origin_xy = scene.origin_xy
            self.mapper.reset()

    def _reset_beliefs(self) -> None:
        """What the robots believe of their poses and the targets they marked: the true arrays
        themselves when noise is off, copies that the noisy path (:mod:`areasearch.sim.noise`) moves
        apart otherwise."""
        self.believed_poses = self.poses.copy() if self._imperfect else self.poses
        """(R, 3) where each robot believes it is (its odometry): what the map is fused at and the planners
        read; the true :attr:`poses` themselves (the same array) when noise is off."""
        self.believed_previous_xy = self.previous_xy.copy() if self._imperfect else self.previous_xy
        """(R, 2) each believed centre before the last step."""
        self.believed_trajectory = self.trajectory.copy() if self._imperfect else self.trajectory
        """(max_steps + 1, R, 3) the believed poses of every step (:attr:`trajectory`: the true ones)."""
        self.target_map_cells = self.target_cells
        """(K, 2) the cells where the targets are marked on the map (:attr:`target_cells` themselves when
        noise is off; else where the robot that detected each believed it was)."""
        self.target_map_xy = self.targets_xy
        """(K, 2) the points the robots believe the targets at, metres (:attr:`targets_xy` when noise is off)."""
        if self.noise is not None:
            self.noise.map_cells = self.target_map_cells = self.target_cells.copy()
            self.noise.map_xy = self.target_map_xy = self.targets_xy.copy()
            self._targets = TargetState(
                self.targets_xy, self._target_id_flat, self._free_flat, self.discovered, self.discovered_at,
                self.covered, self.covered_at, self._counts, self.previous_xy, self._cover_r2, self._swept,
            )  # fmt: skip
        self.knowledge = None
        if self.config.comm.active and self.noise is not None and self.scene is not None:
            self.knowledge = TeamKnowledge(self.config, self.scene, len(self.target_cells), self.noise.rng)

    # ------------------------------------------------------------------------------- step
    def step(self, actions: np.ndarray) -> StepResult:
        """Apply one primitive action per robot (``(R,)`` ints of :class:`Action`)."""
        if self.scene is None or self.mapper is None:
            raise RuntimeError("World.step called before World.reset")
        cfg = self.config
        acts = actions if type(actions) is np.ndarray and actions.dtype == np.int64 else np.asarray(actions)
        if acts.shape != (cfg.num_robots,) or acts.dtype.kind not in "iu":
            raise ConfigError(f"actions must be {cfg.num_robots} integers, got {actions!r}")
        if self._imperfect:
            return self._step_noisy(acts)
        m = self.metrics
        valid = _move_kernel(
            self.poses,
            acts if acts.dtype == np.int64 else acts.astype(np.int64),
            self._obstacles,
            self._cell_m,
            self._origin_x,
            self._origin_y,
            cfg.robot.forward_m,
            cfg.robot.turn_rad,
            cfg.robot.radius_m,
            self._blocked_by,
            m.collisions,
            m.path_length_m,
            self.previous_xy,
        )
        if not valid:
            raise ConfigError(
                f"actions must be in 0..{len(Action) - 1} ({', '.join(a.name for a in Action)}), got {acts}"
            )
        m.steps += 1
        if m.steps < len(self.trajectory):
            self.trajectory[m.steps] = self.poses
        before_m2, before_cov, before_disc = m.explored_m2, m.covered, m.discovered
        self._sense()
        self._update_metrics()
        new_m2 = m.explored_m2 - before_m2
        new_cov = m.covered - before_cov
        rw = cfg.reward
        reward = rw.explore_per_m2 * new_m2 + rw.cover_per_target * new_cov + rw.time_per_step
        blocked_by = self._blocked_by.copy()
        return StepResult(reward, new_m2, new_cov, m.discovered - before_disc, blocked_by > 0, blocked_by)

    def _step_noisy(self, acts: np.ndarray) -> StepResult:
        """:meth:`step` on the noisy path (:mod:`areasearch.sim.noise`): the same moves, one robot after
        another, with noisy distances and angles; the believed poses follow by odometry."""
        cfg, m, nz = self.config, self.metrics, self.noise
        assert nz is not None
        if ((acts < 0) | (acts > 3)).any():
            raise ConfigError(
                f"actions must be in 0..{len(Action) - 1} ({', '.join(a.name for a in Action)}), got {acts}"
            )
        n = cfg.num_robots
        before = self.poses.copy()
        self.previous_xy[:] = before[:, :2]
        self.believed_previous_xy[:] = self.believed_poses[:, :2]
        forward, turn = nz.commands(n, cfg.robot.forward_m, cfg.robot.turn_rad)
        one, blocked, scratch = np.full(n, int(Action.STAY), dtype=np.int64), np.zeros(n, np.int8), np.empty((n, 2))
        for r in range(n):  # one robot at a time, each seeing the others' updated positions
            one[r] = acts[r]
            _move_kernel(
                self.poses, one, self._obstacles, self._cell_m, self._origin_x, self._origin_y, forward[r], turn[r],
                cfg.robot.radius_m, blocked, m.collisions, m.path_length_m, scratch,
            )  # fmt: skip
            one[r] = int(Action.STAY)
            self._blocked_by[r] = blocked[r]
        nz.odometry(before, self.poses, self.believed_poses)
        m.steps += 1
        if m.steps < len(self.trajectory):
            self.trajectory[m.steps] = self.poses
            self.believed_trajectory[m.steps] = self.believed_poses
        before_m2, before_cov, before_disc = m.explored_m2, m.covered, m.discovered
        self._sense_noisy()
        self._update_metrics()
        new_m2, new_cov = m.explored_m2 - before_m2, m.covered - before_cov
        rw = cfg.reward
        reward = rw.explore_per_m2 * new_m2 + rw.cover_per_target * new_cov + rw.time_per_step
        blocked_by = self._blocked_by.copy()
        return StepResult(reward, new_m2, new_cov, m.discovered - before_disc, blocked_by > 0, blocked_by)

    # ------------------------------------------------------------------------------- internals
    def _sense_noisy(self) -> None:
        """Sensing on the noisy path: render at the true poses, add depth noise, fuse into the map at the
        believed poses, then count the truly seen floor, detect and cover (:func:`areasearch.sim.noise.sense`)."""
        nz, mapper, cfg = self.noise, self.mapper, self.config
        assert nz is not None and mapper is not None
        origin = (self._origin_x, self._origin_y)
        render_depth(self._height, self._cell_m, origin, self.poses, cfg.camera, nz.clean, self._h_max)
        nz.perturb(self.depth)
        mapper.integrate(self.depth, cfg.camera, self.believed_poses)
        known = self.knowledge
        if known is not None:
            known.integrate(self.depth, cfg.camera, self.believed_poses)
        sense(nz, self.poses, self.believed_poses, mapper, self._targets, self.metrics.steps, known)
        if known is not None:
            known.share(self.metrics.steps, self.poses[:, :2], self.believed_poses[:, :2], nz.map_cells)

    def _sense(self) -> None:
        """Render the depth images, fuse them into the map (``Mapper.integrate``'s work, driven here
        in one kernel call with the camera tables cached at reset), discover and cover targets."""
        mapper, cfg, tables = self.mapper, self.config, self._tables
        assert mapper is not None
        mapper.integrations += 1
        sense_kernel(
            self._height, self._cell_m, self._origin_x, self._origin_y, self.poses, tables.xu, tables.slope,
            tables.floor_depth, tables.z_max, cfg.camera.mount_height_m, cfg.camera.max_range_m, self._h_max,
            self.depth, mapper.floor_tolerance_m, mapper.obstacle_top_m, mapper.explored, mapper.occupied,
            mapper.occupied_at, mapper.integrations, mapper.new_cells, self._free_flat, self._target_id_flat,
            self.target_cells, self.targets_xy, self.previous_xy, self._cover_r2, self._swept, self.metrics.steps,
            self.discovered,
            self.discovered_at, self.covered, self.covered_at, mapper.targets, self._counts, self._sensed,
        )  # fmt: skip

    def _update_metrics(self) -> None:
        m, cfg = self.metrics, self.config
        k = len(self.covered)
        explored_free, m.discovered, m.covered = self._counts.tolist()
        m.explored_m2 = explored_free * self._cell_area
        m.explored_fraction = explored_free / self._free_cells
        m.covered_fraction = m.covered / k if k else 1.0
        if not m.reached_e:
            m.reached_e = m.explored_fraction >= cfg.success_fraction
            m.time_e = m.steps if m.reached_e else cfg.max_steps
        if not m.reached_c:
            m.reached_c = m.covered_fraction >= cfg.success_fraction
            m.time_c = m.steps if m.reached_c else cfg.max_steps

    # ------------------------------------------------------------------------------- queries
    @property
    def placement_radius_m(self) -> float:
        """Under the ``passby`` protocol, targets lie within this distance of a cell the team can reach:
        the cover radius less half a forward step, so a robot driving up to a target in 0.25 m steps
        always gets close enough. (Under ``paper`` they lie on such cells: :func:`coverable_cells`.)"""
        return placement_radius_m(self.config)

    @property
    def robot_maps(self) -> list[Mapper]:
        """Each robot's map: its own (its group's, merged, after each step) under limited communication,
        else the team's :attr:`mapper` for every robot."""
        if self.knowledge is not None:
            return self.knowledge.maps
        assert self.mapper is not None
        return [self.mapper] * self.config.num_robots

    @property
    def comm_groups(self) -> list[np.ndarray]:
        """The groups of robots that could talk at the last step (sorted robot indices); one group of all
        with full communication."""
        if self.knowledge is not None:
            return self.knowledge.groups
        return [np.arange(self.config.num_robots, dtype=np.int64)]

    def pending_targets(self, robot: int) -> np.ndarray:
        """(K,) bool: the targets ``robot`` knows are discovered and not covered (with full communication,
        every robot knows every discovered target)."""
        if self.knowledge is None:
            return self.discovered & ~self.covered
        return self.knowledge.found[robot] & ~self.knowledge.cleared[robot]

    def team_poses(self, robot: int) -> np.ndarray:
        """(R, 3) where ``robot`` places its team: the believed poses of its group now, every other robot at
        the believed pose it had when ``robot``'s group last heard of it (its start pose if never, the
        team's start being known); :attr:`believed_poses` itself with full communication."""
        if self.knowledge is None:
            return self.believed_poses
        n = self.config.num_robots
        heard = np.clip(self.knowledge.heard.steps[robot], 0, len(self.believed_trajectory) - 1)
        poses = self.believed_trajectory[heard, np.arange(n)]
        group = self.knowledge.group_of(robot)
        poses[group] = self.believed_poses[group]
        return poses

    @property
    def heard(self) -> CommState | None:
        """Where each robot last heard of each team-mate (None with full communication: always now)."""
        return None if self.knowledge is None else self.knowledge.heard

    @property
    def done(self) -> bool:
        """Everything reachable explored and every target covered."""
        return bool(self._counts[0] >= self._free_cells and self._counts[2] == len(self.covered))

    @property
    def all_explored(self) -> bool:
        return bool(self._counts[0] >= self._free_cells)


RESET_OPTIONS = ("poses",)
"""Keys the environments' ``reset(options=...)`` take: ``poses``, (R, 3) start poses."""


def start_poses_option(options: dict | None) -> Any:
    """The ``poses`` of an environment's ``reset(options=...)`` (None: draw them). Other keys are
    ignored, as Gymnasium and PettingZoo environments do (their API checks pass options of their own)."""
    return (options or {}).get("poses")
