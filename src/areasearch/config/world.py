"""The search world's configuration: robots, camera, coverage protocol, targets, reward, noise,
detection and communication (:class:`WorldConfig` and its parts; noise and detection in :mod:`.noise`,
communication in :mod:`.comm`), each field documented where it is declared, with its unit.

Defaults follow the DA-HGNN paper (Zhu, Cheng, Liu and Zhang, "Dual-Attention Heterogeneous Graph
Neural Network for Multi-robot Collaborative Area Search via Deep Reinforcement Learning", section
"Experiment Setup"); where it is silent, its closest public relative NCM (Ye et al., CVPR 2022,
"Multi-Robot Active Mapping via Neural Bipartite Graph Matching", code siyandong/NeuralCoMapping),
whose simulator set-up it shares. A field taken from either says so where it is declared; the
others are ours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from ..errors import ConfigError
from .checks import brief, integer, number, positive, within
from .comm import CommConfig
from .mapping import MappingConfig
from .noise import DetectionConfig, NoiseConfig


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
            positive(f"robot.{name}", getattr(self, name), maximum)
        positive("robot.turn_deg", self.turn_deg)
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
        if not 0.0 < number("camera.hfov_deg", self.hfov_deg) < 180.0:
            raise ConfigError(f"camera.hfov_deg must be in (0, 180), got {self.hfov_deg}")
        for name in ("width_px", "height_px"):
            integer(f"camera.{name}", getattr(self, name), 2, 4096)
        for name, maximum in CAMERA_LIMITS.items():
            positive(f"camera.{name}", getattr(self, name), maximum)


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


ProtocolName = Literal["paper", "passby"]
"""The names of the coverage protocols (the keys of :data:`PROTOCOLS`), the type of ``WorldConfig.protocol``."""

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

``passby`` is a looser rule: a robot centre within 0.3 m (the footprint radius plus
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
        integer("targets.count", self.count, 0, 100_000)
        if self.cover_radius_m is not None:
            positive("targets.cover_radius_m", self.cover_radius_m, 100.0)


@dataclass(frozen=True)
class RewardConfig:
    """Team reward of the paper: r_t = a1 (S^e_t - S^e_{t-1}) + a2 (newly covered) + a3."""

    explore_per_m2: float = 0.01
    """a1: reward per square metre of newly explored reachable free area. The paper gives no values;
    these make coverage, the scored task, most of the return: 100 targets are worth 10, the whole
    of a map's exploration 0.1-0.3 (small training maps), 0.4-0.6 (medium), 0.9-9.7 (large); with
    0.1 / 0.05, exploration is 85-99 % of the return on medium and large maps and coverage is
    drowned out (docs/dahgnn.md#reward)."""
    cover_per_target: float = 0.1
    """a2: reward per newly covered target."""
    time_per_step: float = -0.001
    """a3: reward added every step (a time penalty, so negative): -3.6 over the 3,600-step horizon,
    which the team saves by finishing (every target covered, every reachable cell explored) early."""

    def validate(self) -> None:
        for name in ("explore_per_m2", "cover_per_target", "time_per_step"):
            within(f"reward.{name}", getattr(self, name), -MAX_REWARD, MAX_REWARD)


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
    protocol: ProtocolName = "paper"
    """Coverage protocol, a name of :data:`PROTOCOLS`: ``paper`` (a robot centre passes over the
    target's cell) or ``passby`` (within 0.3 m at the end of a step, a looser rule)."""
    robot: RobotConfig = field(default_factory=RobotConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    targets: TargetConfig = field(default_factory=TargetConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    """Motion and sensing noise (:class:`~areasearch.config.noise.NoiseConfig`); off by default."""
    detection: DetectionConfig = field(default_factory=DetectionConfig)
    """How targets in view are detected (:class:`~areasearch.config.noise.DetectionConfig`); certain by default."""
    comm: CommConfig = field(default_factory=CommConfig)
    """Which robots can talk to which (:class:`~areasearch.config.comm.CommConfig`); all, always by default."""
    mapping: MappingConfig = field(default_factory=MappingConfig)
    """How the mapper keeps occupancy (:class:`~areasearch.config.mapping.MappingConfig`); sticky by default."""

    def validate(self) -> WorldConfig:
        """Raise :class:`ConfigError` naming the first bad field; return self when all is well."""
        if integer("num_robots", self.num_robots, 1) > MAX_ROBOTS:
            raise ConfigError(f"num_robots must be an integer from 1 to {MAX_ROBOTS}, got {brief(self.num_robots)}")
        integer("max_steps", self.max_steps, 1, MAX_STEPS)
        positive("wall_height_m", self.wall_height_m, 100.0)
        if not 0.0 < number("success_fraction", self.success_fraction) <= 1.0:
            raise ConfigError(f"success_fraction must be in (0, 1], got {self.success_fraction}")
        self.robot.validate()
        self.camera.validate()
        self.targets.validate()
        self.reward.validate()
        self.noise.validate()
        self.detection.validate()
        self.comm.validate()
        self.mapping.validate()
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
                f"protocol must be one of {', '.join(repr(p) for p in PROTOCOLS)}, got {brief(self.protocol)}"
            )
        return rule

    @property
    def imperfect(self) -> bool:
        """Some noise is on, detection is not certain, communication is limited or occupancy is not sticky:
        the world runs its noisy path."""
        return self.noise.active or self.detection.active or self.comm.active or self.mapping.active

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
