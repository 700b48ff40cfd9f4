"""Typed, frozen configuration of the search world, one dataclass per concern.

Every field is documented where it is declared, with its unit. Derived quantities are
properties. Variants come from :func:`dataclasses.replace` or :func:`override`, which also
accepts dotted keys (``"camera.width_px"``) so that entry points can take ``**overrides``.

Defaults follow the DA-HGNN paper (../shared/paper/da-hgnn.tex, "Experiment Setup") and, where
it is silent, its closest public relative NCM (Ye et al., CVPR 2022): see REFERENCE-SETTINGS.md.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from .errors import ConfigError


@dataclass(frozen=True)
class RobotConfig:
    """Body and motion of one robot (a TurtleBot-like differential drive)."""

    radius_m: float = 0.18
    """Radius of the circular footprint, metres."""
    height_m: float = 0.6
    """Robot height, metres: the mapper marks points between the floor and this height as obstacles."""
    forward_m: float = 0.25
    """Distance of one FORWARD action, metres."""
    turn_deg: float = 10.0
    """Angle of one TURN_LEFT / TURN_RIGHT action, degrees."""

    @property
    def turn_rad(self) -> float:
        return math.radians(self.turn_deg)

    def validate(self) -> None:
        _positive("robot.radius_m", self.radius_m)
        _positive("robot.height_m", self.height_m)
        _positive("robot.forward_m", self.forward_m)
        _positive("robot.turn_deg", self.turn_deg)
        if self.turn_deg >= 180.0:
            raise ConfigError(f"robot.turn_deg must be below 180, got {self.turn_deg}")


@dataclass(frozen=True)
class CameraConfig:
    """A level pinhole depth camera on each robot, looking along the robot's heading."""

    hfov_deg: float = 90.0
    """Horizontal field of view, degrees (the vertical one follows from square pixels)."""
    width_px: int = 64
    """Image width, pixels."""
    height_px: int = 48
    """Image height, pixels."""
    max_range_m: float = 3.2
    """Farthest measured distance (Euclidean, camera to point), metres; farther pixels read 0 (no return)."""
    mount_height_m: float = 0.5
    """Height of the optical centre above the floor, metres."""

    @property
    def fx(self) -> float:
        """Focal length in pixels (square pixels: fy == fx)."""
        return (self.width_px / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def fy(self) -> float:
        return self.fx

    @property
    def cx(self) -> float:
        return (self.width_px - 1) / 2.0

    @property
    def cy(self) -> float:
        return (self.height_px - 1) / 2.0

    def validate(self) -> None:
        if not 0.0 < _number("camera.hfov_deg", self.hfov_deg) < 180.0:
            raise ConfigError(f"camera.hfov_deg must be in (0, 180), got {self.hfov_deg}")
        for name in ("width_px", "height_px"):
            _integer(f"camera.{name}", getattr(self, name), 2)
        _positive("camera.max_range_m", self.max_range_m)
        _positive("camera.mount_height_m", self.mount_height_m)


@dataclass(frozen=True)
class TargetConfig:
    """The targets to cover (people to rescue)."""

    count: int = 100
    """Number of targets per episode (paper: 100), placed uniformly on coverable free cells."""
    cover_radius_m: float = 0.3
    """A discovered target is covered when a robot centre comes within this distance, metres.

    0.3 m is the footprint radius plus 12 cm: a robot has to drive up to a target on purpose.
    With the 3.2 m camera, exploring alone leaves most targets uncovered (see README, "Targets").
    """

    def validate(self) -> None:
        _integer("targets.count", self.count, 0)
        _positive("targets.cover_radius_m", self.cover_radius_m)


@dataclass(frozen=True)
class RewardConfig:
    """Team reward of the paper: r_t = a1 (S^e_t - S^e_{t-1}) + a2 (newly covered) + a3."""

    explore_per_m2: float = 0.1
    """a1: reward per square metre of newly explored reachable free area."""
    cover_per_target: float = 0.05
    """a2: reward per newly covered target."""
    time_per_step: float = -0.0005
    """a3: reward added every step (a time penalty, so negative)."""

    def validate(self) -> None:
        for name in ("explore_per_m2", "cover_per_target", "time_per_step"):
            _number(f"reward.{name}", getattr(self, name))


@dataclass(frozen=True)
class WorldConfig:
    """Root configuration of the search world."""

    num_robots: int = 3
    """Team size (paper: 3, 4, 5); 1 to 8."""
    max_steps: int = 3600
    """Horizon in primitive steps (paper's test horizon); the episode is truncated there."""
    wall_height_m: float = 2.5
    """Height of walls extruded from occupied map cells, metres."""
    success_fraction: float = 0.8
    """Time_E / Time_C are the first steps at which explored / covered reach this fraction."""
    robot: RobotConfig = field(default_factory=RobotConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    targets: TargetConfig = field(default_factory=TargetConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)

    def validate(self) -> WorldConfig:
        """Raise :class:`ConfigError` naming the first bad field; return self when all is well."""
        if _integer("num_robots", self.num_robots, 1) > MAX_ROBOTS:
            raise ConfigError(f"num_robots must be an integer from 1 to {MAX_ROBOTS}, got {self.num_robots!r}")
        _integer("max_steps", self.max_steps, 1)
        _positive("wall_height_m", self.wall_height_m)
        if not 0.0 < _number("success_fraction", self.success_fraction) <= 1.0:
            raise ConfigError(f"success_fraction must be in (0, 1], got {self.success_fraction}")
        self.robot.validate()
        self.camera.validate()
        self.targets.validate()
        self.reward.validate()
        if self.camera.mount_height_m >= self.wall_height_m:
            raise ConfigError("camera.mount_height_m must be below wall_height_m")
        return self


MAX_ROBOTS = 8


def _number(name: str, value: Any) -> float:
    """``value`` as a finite float, or ConfigError naming the field."""
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ConfigError(f"{name} must be a finite number, got {value!r}")
    return float(value)


def _integer(name: str, value: Any, minimum: int) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
        raise ConfigError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return value


def _positive(name: str, value: Any) -> None:
    if _number(name, value) <= 0:
        raise ConfigError(f"{name} must be a positive number, got {value!r}")


def override(config: Any, **changes: Any) -> Any:
    """Return a copy of a config dataclass with fields replaced.

    Keys may be dotted (``"camera.width_px"``) or use a double underscore (``camera__width_px``)
    to reach nested configs. Unknown keys raise :class:`ConfigError`.
    """
    nested: dict[str, dict[str, Any]] = {}
    flat: dict[str, Any] = {}
    names = {f.name for f in dataclasses.fields(config)}
    for key, value in changes.items():
        head, sep, rest = key.replace("__", ".").partition(".")
        if head not in names:
            raise ConfigError(f"unknown setting {key!r} for {type(config).__name__}; known: {sorted(names)}")
        if sep:
            nested.setdefault(head, {})[rest] = value
        else:
            flat[head] = value
    for head, value in flat.items():
        current = getattr(config, head)
        if dataclasses.is_dataclass(current) and not isinstance(value, type(current)):
            raise ConfigError(
                f"setting {head!r} is a group of settings; set its fields ({head}.<field>=...), got {value!r}"
            )
    for head, sub in nested.items():
        inner = flat.get(head, getattr(config, head))
        if not dataclasses.is_dataclass(inner):
            raise ConfigError(f"setting {head!r} has no sub-fields")
        flat[head] = override(inner, **sub)
    return dataclasses.replace(config, **flat)


@dataclass(frozen=True)
class CandidateConfig:
    """Candidate goals: frontier nodes and target nodes (DA-HGNN "Topological Planner")."""

    min_frontier_cells: int = 3
    """Frontier fragments smaller than this are dropped, unless they are all that is left."""
    cluster_m: float = 1.0
    """A connected frontier longer than this is split into several nodes, metres."""
    exhausted_m: float = 0.5
    """Frontier nodes this close to an exhausted one (reached and looked at, still there) are dropped."""
    max_candidates: int = 256
    """Candidates offered to the planner per decision; beyond it, targets first, then the frontier
    nodes nearest to the team are kept (observation arrays are padded to this size)."""

    def validate(self) -> None:
        _integer("candidates.min_frontier_cells", self.min_frontier_cells, 1)
        _positive("candidates.cluster_m", self.cluster_m)
        _positive("candidates.exhausted_m", self.exhausted_m)
        _integer("candidates.max_candidates", self.max_candidates, 1)


@dataclass(frozen=True)
class PathConfig:
    """The FMM action planner (DA-HGNN "Action Planner and Execution")."""

    goal_tolerance_m: float = 0.25
    """A robot this close to its long-term goal has arrived and stays, metres."""
    lookahead_m: float = 0.5
    """The short-term goal is this far ahead along the path, metres."""
    check_ahead_m: float = 0.5
    """Each step, this much of the path ahead is checked for newly mapped obstacles, metres."""
    unknown_margin_m: float = 0.5
    """Unknown cells are traversable up to this far beyond a frontier, metres (as for candidates)."""
    local_margin_m: float = 1.0
    """Paths are first sought in the box around the robot and its goal grown by this much, metres
    (then, if none is found there, over the whole map)."""
    bump_memory_steps: int = 200
    """Steps a bumped cell stays impassable for planning."""
    robot_wait_steps: int = 2
    """Steps a robot blocked by a team-mate waits before it re-plans around the other robots."""
    robot_wait_limit: int = 20
    """Blocked tries behind team-mates, without moving, after which a goal counts as unreachable."""
    look_radius_m: float = 1.0
    """On arrival a robot turns towards the unknown cells within this distance of its goal, metres."""
    max_bumps: int = 8
    """Bumps into obstacles, without moving in between, after which a goal counts as unreachable."""
    primitive_search_m: float = 1.0
    """A robot about to drive into a mapped obstacle (by the world's collision rule) plans its next
    moves with the motion primitives instead (A* over the poses FORWARD and the turns reach), to its
    goal if the goal is this close, else to the point of its path this far ahead, metres; 0: never."""
    primitive_search_expansions: int = 20000
    """Most poses one primitive search expands before it gives up (the heading heuristic then acts)."""

    def validate(self) -> None:
        _positive("paths.goal_tolerance_m", self.goal_tolerance_m)
        _positive("paths.lookahead_m", self.lookahead_m)
        _positive("paths.check_ahead_m", self.check_ahead_m)
        _positive("paths.look_radius_m", self.look_radius_m)
        _positive("paths.local_margin_m", self.local_margin_m)
        _integer("paths.max_bumps", self.max_bumps, 1)
        _integer("paths.robot_wait_steps", self.robot_wait_steps, 0)
        _integer("paths.robot_wait_limit", self.robot_wait_limit, 1)
        _integer("paths.bump_memory_steps", self.bump_memory_steps, 1)
        _integer("paths.primitive_search_expansions", self.primitive_search_expansions, 1)
        if _number("paths.primitive_search_m", self.primitive_search_m) < 0:
            raise ConfigError(f"paths.primitive_search_m must be >= 0, got {self.primitive_search_m!r}")
        if _number("paths.unknown_margin_m", self.unknown_margin_m) < 0:
            raise ConfigError(f"paths.unknown_margin_m must be >= 0, got {self.unknown_margin_m!r}")


@dataclass(frozen=True)
class DecisionConfig:
    """The high-level decision process: one long-term goal per robot every ``period_steps``."""

    period_steps: int = 40
    """Primitive steps between two decisions (paper: 40)."""
    history: int = 8
    """Past decisions kept in the observation (historical robot positions and goals)."""
    failed_memory: int = 5
    """Decisions during which a goal that proved unreachable for a robot is not offered to it again."""
    map_cells: int = 128
    """Side of the square observation map, cells after downsampling."""
    map_downsample: int = 4
    """Smallest downsampling factor of the observation map (paper: 4); larger maps use the factor
    that makes them fit ``map_cells``."""

    def validate(self) -> None:
        for name in ("period_steps", "history", "failed_memory", "map_cells", "map_downsample"):
            _integer(f"decisions.{name}", getattr(self, name), 1)


@dataclass(frozen=True)
class SearchConfig:
    """Root configuration of the high-level (goal-assignment) environment."""

    world: WorldConfig = field(default_factory=WorldConfig)
    candidates: CandidateConfig = field(default_factory=CandidateConfig)
    paths: PathConfig = field(default_factory=PathConfig)
    decisions: DecisionConfig = field(default_factory=DecisionConfig)

    def validate(self) -> SearchConfig:
        self.world.validate()
        self.candidates.validate()
        self.paths.validate()
        self.decisions.validate()
        return self
