"""The real world's imperfections: motion and sensing noise (:class:`NoiseConfig`) and target detection
(:class:`DetectionConfig`), the ``noise`` and ``detection`` groups of :class:`~areasearch.config.WorldConfig`.

Every field is off by default (no noise, every target in view detected), so that a world configured
without them is the noise-free world. Where a value is taken from elsewhere, its field says so: the
action noise and the depth dropout follow NCM (Ye et al., CVPR 2022, "Multi-Robot Active Mapping via
Neural Bipartite Graph Matching", code siyandong/NeuralCoMapping, on iGibson); the other models are ours.
Their defaults are 0 (off); the values a field names as its source's are what a realistic setting takes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from ..errors import ConfigError
from .checks import brief, within

MAX_NOISE = 1.0
"""Largest relative noise (a fraction): an error as large as the move itself."""


@dataclass(frozen=True)
class NoiseConfig:
    """Motion and sensing noise of every robot; all 0 (off) by default."""

    forward: float = 0.0
    """Action noise of a FORWARD, a fraction: the distance driven is ``robot.forward_m * (1 + e)``, ``e``
    uniform in [-forward, forward], drawn per robot and step. NCM (iGibson) perturbs each wheel command
    uniformly by ±2.5 %: 0.025."""
    turn: float = 0.0
    """Action noise of a turn, a fraction: the angle turned is ``robot.turn_deg * (1 + e)``, ``e`` uniform
    in [-turn, turn]. NCM's ±2.5 % on the wheel commands: 0.025."""
    odometry_forward: float = 0.0
    """Odometry error of a distance driven, a fraction: the robot believes it drove the true distance
    times ``1 + e``, ``e`` normal with this standard deviation, per robot and move (ours). The believed
    pose drifts from the true one by a random walk: after n straight moves of d metres the mean error
    is ``d * odometry_forward * sqrt(2 n / pi)``."""
    odometry_turn: float = 0.0
    """Odometry error of an angle turned, a fraction: the robot believes it turned the true angle times
    ``1 + e``, ``e`` normal with this standard deviation (ours). A heading error turns every later move
    of the believed pose, so the position error grows faster than by ``odometry_forward`` alone."""
    depth: float = 0.0
    """Range noise of the depth camera, a fraction of the depth: each pixel's z-depth is ``z * (1 + e)``,
    ``e`` normal with this standard deviation, drawn per pixel and frame, so the error grows in
    proportion to the distance (ours; a stereo or time-of-flight sensor's error grows with range)."""
    dropout: float = 0.0
    """Depth pixel dropout, a probability: each pixel returns nothing (0) with it, per pixel and frame,
    as NCM's depth noise drops pixels (its value is not part of its public settings; ours to set)."""

    def validate(self) -> None:
        for name in ("forward", "turn", "odometry_forward", "odometry_turn", "depth"):
            within(f"noise.{name}", getattr(self, name), 0.0, MAX_NOISE)
        within("noise.dropout", self.dropout, 0.0, 1.0)

    @property
    def active(self) -> bool:
        """Some noise is on."""
        return any((self.forward, self.turn, self.odometry_forward, self.odometry_turn, self.depth, self.dropout))


DetectionModel = Literal["certain", "constant", "linear"]
"""The names of the detection models (``DetectionConfig.model``)."""

DETECTION_MODELS = ("certain", "constant", "linear")


@dataclass(frozen=True)
class DetectionConfig:
    """How a robot detects a target in view: a target is in view of a frame when its cell is among the
    cells that frame shows (its camera sees the cell's floor or sees through it, by the true geometry);
    each frame that shows it detects it with a probability, drawn per robot, frame and target."""

    model: DetectionModel = "certain"
    """``certain``: every target in view is detected (probability 1; the noise-free rule). ``constant``:
    with probability ``p_near`` per frame. ``linear``: ``p_near`` at 0 m falling linearly to ``p_far``
    at the camera's ``max_range_m`` (distance camera to target cell centre, on the floor plane). Ours."""
    p_near: float = 1.0
    """Detection probability per frame at 0 m (``constant``: at every distance), in [0, 1]."""
    p_far: float = 1.0
    """Detection probability per frame at the camera's range (``linear`` only), in [0, 1]."""

    def validate(self) -> None:
        if self.model not in DETECTION_MODELS:
            names = ", ".join(repr(m) for m in DETECTION_MODELS)
            raise ConfigError(f"detection.model must be one of {names}, got {brief(self.model)}")
        within("detection.p_near", self.p_near, 0.0, 1.0)
        within("detection.p_far", self.p_far, 0.0, 1.0)

    @property
    def active(self) -> bool:
        """Detection is not certain."""
        return self.model != "certain"

    def probability(self, distance_m: float, max_range_m: float) -> float:
        """The probability that one frame detects a target in view ``distance_m`` from the camera."""
        if self.model == "certain":
            return 1.0
        if self.model == "constant":
            return self.p_near
        t = min(max(distance_m / max_range_m, 0.0), 1.0) if math.isfinite(distance_m) else 1.0
        return self.p_near + (self.p_far - self.p_near) * t
