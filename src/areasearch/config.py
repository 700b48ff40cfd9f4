"""Typed, frozen configuration of the search world, one dataclass per concern.

Every field is documented where it is declared, with its unit. Derived quantities are
properties. Variants come from :func:`dataclasses.replace` or :func:`override`, which also
accepts dotted keys (``"camera.width_px"``) so that entry points can take ``**overrides``. The
command line's ``--set KEY=VALUE`` options are read by :func:`parse_settings` and applied to a
:class:`SearchConfig` by :func:`search_config`.

Defaults follow the DA-HGNN paper (Zhu, Cheng, Liu and Zhang, "Dual-Attention Heterogeneous Graph
Neural Network for Multi-robot Collaborative Area Search via Deep Reinforcement Learning", section
"Experiment Setup"); where it is silent, its closest public relative NCM (Ye et al., CVPR 2022,
"Multi-Robot Active Mapping via Neural Bipartite Graph Matching", code siyandong/NeuralCoMapping),
whose simulator set-up it shares. A field taken from either says so where it is declared; the
others are ours.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from .errors import ConfigError
from .inputs import int_digits_message, is_int_digits_error


@dataclass(frozen=True)
class RobotConfig:
    """Body and motion of one robot: a TurtleBot-like differential drive (DA-HGNN uses iGibson's Turtle
    robot model; the sizes and step lengths are ours)."""

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
        for name, maximum in ROBOT_LIMITS.items():
            _positive(f"robot.{name}", getattr(self, name), maximum)
        _positive("robot.turn_deg", self.turn_deg)
        if self.turn_deg >= 180.0:
            raise ConfigError(f"robot.turn_deg must be below 180, got {self.turn_deg}")


@dataclass(frozen=True)
class CameraConfig:
    """A level pinhole depth camera on each robot, looking along the robot's heading."""

    hfov_deg: float = 90.0
    """Horizontal field of view, degrees (the vertical one follows from square pixels); NCM's 90°."""
    width_px: int = 64
    """Image width, pixels (ours; NCM's camera is 192 x 192)."""
    height_px: int = 48
    """Image height, pixels."""
    max_range_m: float = 3.2
    """Farthest measured distance (Euclidean, camera to point), metres; farther pixels read 0 (no return).
    NCM's vision range, 3.2 m."""
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
            _integer(f"camera.{name}", getattr(self, name), 2, 4096)
        for name, maximum in CAMERA_LIMITS.items():
            _positive(f"camera.{name}", getattr(self, name), maximum)


@dataclass(frozen=True)
class Protocol:
    """A coverage rule: when a target counts as covered, and where targets may be placed."""

    name: str
    cover_radius_m: float
    """Default cover radius, metres (the one ``paper`` fixes; ``passby``'s may be set)."""
    swept: bool
    """True: a target is covered when the segment a robot centre sweeps in a step (a FORWARD's
    0.25 m, a point for a turn or a blocked move) passes within the cover radius of the target's
    cell centre. False: only the robot centre's position at the end of the step counts."""
    centre_placement: bool
    """True: targets lie on cells a robot centre can stand on (the team's reachable region, less its
    outermost cells), so every target can be covered by driving the centre over it. False: within
    the cover radius less half a forward step of such a cell (the pass-by rule's placement)."""
    summary: str


PROTOCOLS: dict[str, Protocol] = {
    "paper": Protocol(
        "paper",
        0.05,
        True,
        True,
        "a target is covered when a robot centre passes over its cell (within 0.05 m of the cell "
        "centre along each move's swept segment), as in the DA-HGNN authors' coverage code",
    ),
    "passby": Protocol(
        "passby",
        0.3,
        False,
        False,
        "a target is covered when a robot centre ends a step within 0.3 m of it (a looser rule than the "
        "paper's; keeps the results measured under it reproducible)",
    ),
}
"""The named coverage protocols (``WorldConfig.protocol``).

``paper`` follows the DA-HGNN authors' public code for their earlier paper in the same setting
(``linaug/Role_selection``, ``adversarial_comms/environments/coverage.py``, ``Robot.step``): a
target is covered only when a robot stands on the target's grid cell at the end of a step. DA-HGNN
runs on NCM's simulator (iGibson, 10 cm map cells), so "on the target's cell" is the robot centre
within about half a 10 cm cell of the target: the cover radius is 0.05 m. Our maps have cells of
their own size, so the rule is a radius about the target cell's centre rather than our cell, and it is
checked along the whole swept segment of each move, so that a 0.25 m FORWARD cannot jump over a
target. Cover % = covered / all targets, as in the paper; ``covered_of_discovered_pct`` (covered /
discovered) is what the authors' code reports.

``passby`` is the rule areasearch used before: a robot centre within 0.3 m (the footprint radius plus
12 cm) at the end of a step; it sweeps most targets up on the way while exploring, so every method
covers ~100 % of small and medium maps and Cover % cannot separate methods.
"""


@dataclass(frozen=True)
class TargetConfig:
    """The targets to cover (people to rescue)."""

    count: int = 100
    """Number of targets per episode (paper: 100), placed uniformly on coverable free cells."""
    cover_radius_m: float | None = None
    """Cover radius, metres; None: the protocol's (``paper``: 0.05 m, fixed; ``passby``: 0.3 m, may be
    set). See :data:`PROTOCOLS`; read the radius in force with :attr:`WorldConfig.cover_radius_m`."""

    def validate(self) -> None:
        _integer("targets.count", self.count, 0, 100_000)
        if self.cover_radius_m is not None:
            _positive("targets.cover_radius_m", self.cover_radius_m, 100.0)


@dataclass(frozen=True)
class RewardConfig:
    """Team reward of the paper: r_t = a1 (S^e_t - S^e_{t-1}) + a2 (newly covered) + a3."""

    explore_per_m2: float = 0.01
    """a1: reward per square metre of newly explored reachable free area. The paper gives no values;
    these make coverage, the scored task, most of the return: 100 targets are worth 10, the whole
    of a map's exploration 0.1-0.3 (small training maps), 0.4-0.6 (medium), 0.9-9.7 (large); the
    first release's 0.1 / 0.05 made exploration 85-99 % of the return on medium and large maps
    (docs/dahgnn.md#reward)."""
    cover_per_target: float = 0.1
    """a2: reward per newly covered target."""
    time_per_step: float = -0.001
    """a3: reward added every step (a time penalty, so negative): -3.6 over the 3,600-step horizon,
    which the team saves by finishing (every target covered, every reachable cell explored) early."""

    def validate(self) -> None:
        for name in ("explore_per_m2", "cover_per_target", "time_per_step"):
            _within(f"reward.{name}", getattr(self, name), -MAX_REWARD, MAX_REWARD)


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
    protocol: str = "paper"
    """Coverage protocol, a name of :data:`PROTOCOLS`: ``paper`` (a robot centre passes over the
    target's cell) or ``passby`` (within 0.3 m at the end of a step, the rule of earlier results)."""
    robot: RobotConfig = field(default_factory=RobotConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    targets: TargetConfig = field(default_factory=TargetConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)

    def validate(self) -> WorldConfig:
        """Raise :class:`ConfigError` naming the first bad field; return self when all is well."""
        if _integer("num_robots", self.num_robots, 1) > MAX_ROBOTS:
            raise ConfigError(f"num_robots must be an integer from 1 to {MAX_ROBOTS}, got {_short(self.num_robots)}")
        _integer("max_steps", self.max_steps, 1, MAX_STEPS)
        _positive("wall_height_m", self.wall_height_m, 100.0)
        if not 0.0 < _number("success_fraction", self.success_fraction) <= 1.0:
            raise ConfigError(f"success_fraction must be in (0, 1], got {self.success_fraction}")
        self.robot.validate()
        self.camera.validate()
        self.targets.validate()
        self.reward.validate()
        if self.camera.mount_height_m >= self.wall_height_m:
            raise ConfigError("camera.mount_height_m must be below wall_height_m")
        rule = self.rule
        radius = self.targets.cover_radius_m
        if rule.name == "paper" and radius is not None and radius != rule.cover_radius_m:
            raise ConfigError(
                f"targets.cover_radius_m={radius:g} contradicts protocol 'paper', which covers a target when a "
                f"robot centre passes over its cell ({rule.cover_radius_m:g} m); set protocol=passby to choose "
                "a radius"
            )
        return self

    @property
    def rule(self) -> Protocol:
        """The :class:`Protocol` named by ``protocol`` (ConfigError naming the field if unknown)."""
        rule = PROTOCOLS.get(self.protocol) if isinstance(self.protocol, str) else None
        if rule is None:
            raise ConfigError(
                f"protocol must be one of {', '.join(repr(p) for p in PROTOCOLS)}, got {_short(self.protocol)}"
            )
        return rule

    @property
    def cover_radius_m(self) -> float:
        """The cover radius in force: ``targets.cover_radius_m``, else the protocol's, metres."""
        radius = self.targets.cover_radius_m
        return self.rule.cover_radius_m if radius is None else float(radius)


MAX_ROBOTS = 8
ROBOT_LIMITS = {"radius_m": 5.0, "height_m": 10.0, "forward_m": 10.0}
"""Largest robot lengths, metres: lengths become cell counts and array sizes (a footprint of 1e9 m
would exhaust the memory before any error)."""
CAMERA_LIMITS = {"max_range_m": 1000.0, "mount_height_m": 10.0}
"""Largest camera lengths, metres (the range sets the ray casts' length in cells)."""
MAX_REWARD = 1e6
"""Largest magnitude of a reward weight: a return summed over 10 million steps stays finite in float32."""
MAX_STEPS = 10_000_000
"""Longest horizon, and most steps any count of steps in the settings may be."""
FPS_RANGE = (0.1, 100.0)
"""Frames per second an animation may have (a GIF stores a frame's duration in hundredths of a second)."""


def _short(value: Any, limit: int = 60) -> str:
    """``repr(value)``, cut to ``limit`` characters (user input in a message stays bounded)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _number(name: str, value: Any) -> float:
    """``value`` as a finite float, or ConfigError naming the field."""
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ConfigError(f"{name} must be a finite number, got {_short(value)}")
    return float(value)


def _integer(name: str, value: Any, minimum: int, maximum: int | None = None) -> int:
    """``value`` as an integer >= ``minimum`` (and <= ``maximum``: a bound on what the arrays it
    sizes may cost), or ConfigError naming the field."""
    if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
        raise ConfigError(f"{name} must be an integer >= {minimum}, got {_short(value)}")
    if maximum is not None and value > maximum:
        raise ConfigError(f"{name} must be an integer from {minimum} to {maximum:,}, got {_short(value)}")
    return value


def _within(name: str, value: Any, minimum: float, maximum: float) -> float:
    """A finite number in [``minimum``, ``maximum``], or ConfigError naming the field and the bounds."""
    number = _number(name, value)
    if not minimum <= number <= maximum:
        raise ConfigError(f"{name} must be a number from {minimum:g} to {maximum:g}, got {_short(value)}")
    return number


def _positive(name: str, value: Any, maximum: float | None = None) -> None:
    """A positive finite number (at most ``maximum``: lengths become cell counts and array sizes, so a
    robot of 1e9 m would exhaust the memory before any error), or ConfigError naming the field."""
    if _number(name, value) <= 0:
        raise ConfigError(f"{name} must be a positive number, got {_short(value)}")
    if maximum is not None and value > maximum:
        raise ConfigError(f"{name} must be a positive number of at most {maximum:g}, got {_short(value)}")


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
            raise ConfigError(f"unknown setting {_short(key)} for {type(config).__name__}; known: {sorted(names)}")
        if sep:
            nested.setdefault(head, {})[rest] = value
        else:
            flat[head] = value
    for head, value in flat.items():
        current = getattr(config, head)
        if dataclasses.is_dataclass(current) and not isinstance(value, type(current)):
            raise ConfigError(
                f"setting {head!r} is a group of settings; set its fields ({head}.<field>=...), got {_short(value)}"
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
        _integer("candidates.min_frontier_cells", self.min_frontier_cells, 1, 1_000_000)
        _positive("candidates.cluster_m", self.cluster_m, 100.0)
        _positive("candidates.exhausted_m", self.exhausted_m, 100.0)
        _integer("candidates.max_candidates", self.max_candidates, 1, 4096)


@dataclass(frozen=True)
class PathConfig:
    """The FMM action planner (DA-HGNN "Action Planner and Execution")."""

    goal_tolerance_m: float = 0.25
    """A robot this close to its long-term goal has arrived and stays, metres."""
    lookahead_m: float = 0.5
    """The short-term goal is this far ahead along the path, metres."""
    min_aim_m: float = 0.05
    """A short-term goal nearer than this to the robot's centre is replaced by the first path cell
    beyond it: the heading to a point a few centimetres away is set by where in its cell the robot
    stands, not by the path (a robot backing off in a narrow doorway aimed 3.5 cm west, at a
    team-mate, for ever), metres; the default is one cell of the bundled maps; 0: never. Half a
    FORWARD (0.125 m) was tried and cut corners in the tightest doorways (0.40 m, slanted 60°): the
    bump marks it left closed the doorway to a team of five."""
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
    detour_every_steps: int = 5
    """A robot blocked by a team-mate, once it has waited ``robot_wait_steps``, seeks a detour round the
    team-mates at its next blocked try and then at every this-many-th one (it waits in between); when
    it is still blocked this many steps after its first detour, one of the two robots gives way, steps."""
    give_way_steps: int = 40
    """A robot giving way (driving to a spot off a team-mate's way and waiting there) re-plans to its own
    goal this many steps after it began, steps (the default is twice ``robot_wait_limit``)."""
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
    primitive_search_narrow_expansions: int = 200000
    """In a narrow passage (few cells round the robot where a centre may stand, e.g. a doorway barely
    wider than the robot) a search that found no plan within ``primitive_search_expansions`` is tried
    again with this many: a way through such a passage can take dozens of turns and short moves."""
    primitive_search_pause_steps: int = 40
    """Steps after a primitive search of a robot found no plan, or an obstacle the map did not show
    blocked its plan, before that robot searches again, steps (the default is twice ``robot_wait_limit``)."""
    progress_window_cells: int = 40
    """Each step the path cell nearest the robot (its progress along the path) is sought among this many
    cells of the path from the last one, path cells: progress never goes back, and a path that passes
    near itself further on is not cut short."""
    deadlock_steps: int = 10
    """A robot with a goal that has not moved for this many steps while team-mates block it is in a jam:
    the other robots near it back off the way of the one closest to its goal
    (:mod:`areasearch.planning.paths.jams`), steps."""
    path_buffer_cells: int = 256
    """First length of each robot's path buffer, path cells; a longer path doubles it (memory only: no
    effect on what the robots do)."""
    bump_log_per_robot: int = 64
    """First size of the log of bump marks, bumps per robot (a bump logs up to 6 cells); a fuller log
    doubles (memory only: no effect on what the robots do)."""

    def validate(self) -> None:
        _positive("paths.goal_tolerance_m", self.goal_tolerance_m, 100.0)
        _positive("paths.lookahead_m", self.lookahead_m, 100.0)
        _positive("paths.check_ahead_m", self.check_ahead_m, 100.0)
        _positive("paths.look_radius_m", self.look_radius_m, 100.0)
        _positive("paths.local_margin_m", self.local_margin_m, 100.0)
        # counts of steps and tries are compared with counters (bounded by the horizon); the expansions of a
        # search, the path buffer and the bump log are loop counts and array sizes
        for name, minimum, maximum in (
            ("max_bumps", 1, 1_000_000),
            ("robot_wait_steps", 0, MAX_STEPS),
            ("robot_wait_limit", 1, 1_000_000),
            ("bump_memory_steps", 1, MAX_STEPS),
            ("primitive_search_expansions", 1, 10_000_000),
            ("primitive_search_narrow_expansions", 1, 10_000_000),
            ("detour_every_steps", 1, MAX_STEPS),
            ("give_way_steps", 1, MAX_STEPS),
            ("primitive_search_pause_steps", 0, MAX_STEPS),
            ("progress_window_cells", 1, 1_000_000),
            ("path_buffer_cells", 1, 1_000_000),
            ("deadlock_steps", 1, MAX_STEPS),
            ("bump_log_per_robot", 1, 100_000),
        ):
            _integer(f"paths.{name}", getattr(self, name), minimum, maximum)
        for name in ("primitive_search_m", "min_aim_m", "unknown_margin_m"):
            _within(f"paths.{name}", getattr(self, name), 0.0, 100.0)


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
        # map_cells is the side of the (7, S, S) observation map, history a dimension of its arrays
        for name, maximum in (
            ("period_steps", MAX_STEPS),
            ("history", 1_000),
            ("failed_memory", 1_000_000),
            ("map_cells", 2_048),
            ("map_downsample", 1_024),
        ):
            _integer(f"decisions.{name}", getattr(self, name), 1, maximum)


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


# ---------------------------------------------------------------------------------- --set KEY=VALUE


def parse_settings(pairs: Iterable[str]) -> dict[str, Any]:
    """``KEY=VALUE`` strings (the command line's ``--set`` options) -> ``{KEY: value}``.

    A value is read as JSON where it is JSON (numbers, ``true`` / ``false``, ``null``, lists), else
    kept as text; a later pair with the same key wins. Keys are not checked here (each command knows
    its settings: :func:`search_settings` for the world, the training config for ``train``).
    ConfigError, naming the pair, for a pair without ``=``, an empty key or value, a key with spaces,
    and a non-finite number (``nan``, ``inf``, ``1e999``).
    """
    settings: dict[str, Any] = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        key = key.strip()
        if not sep or not key or not text.strip() or any(c.isspace() for c in key):
            raise ConfigError(f"--set {_short(pair)}: expected KEY=VALUE, e.g. --set robot.radius_m=0.2")
        try:
            value = json.loads(text, parse_constant=_non_finite_constant)
        except ValueError as exc:  # json.JSONDecodeError is a ValueError too
            if is_int_digits_error(exc):
                raise ConfigError(f"--set {_short(pair)}: {key} is {int_digits_message()}") from None
            if not isinstance(exc, json.JSONDecodeError) or text.strip().lower().lstrip("+-") in _NON_FINITE:
                raise ConfigError(f"--set {_short(pair)}: {key} must be a finite number") from None
            value = text
        if not _all_finite(value):
            raise ConfigError(f"--set {_short(pair)}: {key} must be a finite number")
        settings[key] = value
    return settings


_NON_FINITE = ("nan", "inf", "infinity")


def _non_finite_constant(name: str) -> Any:
    raise ValueError(f"non-finite number {name}")


def _all_finite(value: Any) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, list):
        return all(_all_finite(v) for v in value)
    if isinstance(value, dict):
        return all(_all_finite(v) for v in value.values())
    return True


SEARCH_GROUPS = tuple(f.name for f in dataclasses.fields(SearchConfig))
"""The top-level groups of :class:`SearchConfig`; a setting key starting otherwise is a world key."""


def search_key(key: str) -> str:
    """The full dotted :class:`SearchConfig` key of a setting key: ``world.``, ``candidates.``,
    ``paths.`` and ``decisions.`` keys as they are, any other key (``robot.radius_m``,
    ``targets.count``, ``max_steps``) under ``world.``; ``__`` reads as ``.``. Not checked."""
    dotted = key.replace("__", ".")
    return dotted if dotted.split(".", 1)[0] in SEARCH_GROUPS else f"world.{dotted}"


def search_settings(settings: Mapping[str, Any]) -> dict[str, Any]:
    """Settings of the search world by their full keys (:func:`search_key`), sorted, with integers
    given to float fields as floats: the one form of a set of ``--set`` options (for a run's
    ``config.json`` and for worker processes). ConfigError names an unknown key, or a key that is a
    group of settings, and lists the keys known there."""
    out: dict[str, Any] = {}
    for key, value in settings.items():
        full = search_key(key)
        declared = _setting_field(full, key).type  # a string: this module's annotations are postponed
        if "float" in str(declared) and isinstance(value, int) and not isinstance(value, bool):
            if abs(value) > sys.float_info.max:  # float() would raise OverflowError
                raise ConfigError(f"setting {_short(key)} must be a finite number, got an integer beyond the floats")
            value = float(value)
        out[full] = value
    return dict(sorted(out.items()))


def search_config(settings: Mapping[str, Any] | None = None, base: SearchConfig | None = None) -> SearchConfig:
    """``base`` (default: :class:`SearchConfig`) with ``settings`` applied (:func:`search_settings`
    keys), validated. ConfigError names the first unknown key or bad value."""
    return override(base or SearchConfig(), **search_settings(settings or {})).validate()


def _setting_field(full: str, key: str) -> dataclasses.Field[Any]:
    """The dataclass field of the setting at dotted path ``full``; ConfigError naming ``key`` if none."""
    node: Any = SearchConfig()
    found: dataclasses.Field[Any] | None = None
    shown: list[str] = []  # the path as the user writes it (world. left out)
    for i, part in enumerate(full.split(".")):
        if not dataclasses.is_dataclass(node):
            raise ConfigError(f"unknown setting {_short(key)}: {'.'.join(shown)} is a single setting, with no fields")
        fields = {f.name: f for f in dataclasses.fields(node)}
        if part not in fields:
            raise ConfigError(f"unknown setting {_short(key)}; known settings: {_known(node, shown)}")
        found, node = fields[part], getattr(node, part)
        if i > 0 or part != "world":
            shown.append(part)
    if dataclasses.is_dataclass(node):
        raise ConfigError(f"setting {_short(key)} is a group of settings; set one of its fields: {_known(node, shown)}")
    assert found is not None
    return found


def _known(node: Any, shown: list[str]) -> str:
    """The keys known in group ``node`` (at path ``shown``), groups as ``name.*``; at the world's level
    also the other groups of :class:`SearchConfig`."""
    prefix = "".join(f"{part}." for part in shown)
    names = [
        f"{prefix}{f.name}.*" if dataclasses.is_dataclass(getattr(node, f.name)) else f"{prefix}{f.name}"
        for f in dataclasses.fields(node)
    ]
    if isinstance(node, WorldConfig):
        names += [f"{group}.*" for group in SEARCH_GROUPS if group != "world"]
    return ", ".join(names)
