"""How the reconstruction mapper keeps occupancy: the ``mapping`` group of :class:`~areasearch.config.WorldConfig`.

``sticky`` (the default) marks a cell occupied for good the first time a depth point between the floor
tolerance and the robot height falls in it: exact with a perfect depth camera, but one outlier of a noisy
one leaves a phantom obstacle that never clears. ``log_odds`` keeps, per cell, the log-odds of being
occupied and adds each frame's evidence (a probabilistic occupancy grid, as OctoMap does: Hornung, Wurm,
Bennewitz, Stachniss and Burgard, "OctoMap: an efficient probabilistic 3D mapping framework based on
octrees", Autonomous Robots 34(3), 2013), so a cell seen free again clears
(:mod:`areasearch.sim.occupancy`). The probabilities' defaults are OctoMap's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from ..errors import ConfigError
from .checks import brief, number

OccupancyModel = Literal["sticky", "log_odds"]
"""The names of the occupancy models (``MappingConfig.occupancy``)."""

OCCUPANCY_MODELS = ("sticky", "log_odds")


@dataclass(frozen=True)
class MappingConfig:
    """The mapper's occupancy model; ``sticky`` by default (the noise-free world's)."""

    occupancy: OccupancyModel = "sticky"
    """``sticky``: a cell is occupied from the first obstacle point in it on. ``log_odds``: each cell's
    log-odds of occupancy, updated by every frame that sees it and clamped; occupied while positive.
    ``log_odds`` runs on the world's noisy path."""
    p_hit: float = 0.7
    """Probability that a cell is occupied given a frame that votes it hit, unitless in (0.5, 1): adds
    ``log(p_hit / (1 - p_hit))`` (0.85) to the cell's log-odds. OctoMap's 0.7."""
    p_miss: float = 0.4
    """Probability that a cell is occupied given a frame that votes it free, unitless in (0, 0.5): adds
    ``log(p_miss / (1 - p_miss))`` (-0.41). OctoMap's 0.4."""
    p_min: float = 0.12
    """Lower clamp of a cell's occupancy probability, unitless in (0, 0.5): a cell seen free many times
    turns occupied again after a few hit votes (log-odds -1.99). OctoMap's 0.12."""
    p_max: float = 0.97
    """Upper clamp of a cell's occupancy probability, unitless in (0.5, 1) (log-odds 3.48). OctoMap's 0.97."""

    def validate(self) -> None:
        if self.occupancy not in OCCUPANCY_MODELS:
            names = ", ".join(repr(m) for m in OCCUPANCY_MODELS)
            raise ConfigError(f"mapping.occupancy must be one of {names}, got {brief(self.occupancy)}")
        for name in ("p_hit", "p_miss", "p_min", "p_max"):
            if not 0.0 < number(f"mapping.{name}", getattr(self, name)) < 1.0:
                raise ConfigError(f"mapping.{name} must be a probability in (0, 1), got {brief(getattr(self, name))}")
        if not self.p_hit > 0.5:
            raise ConfigError(f"mapping.p_hit must be above 0.5 (a hit is evidence of an obstacle), got {self.p_hit}")
        if not self.p_miss < 0.5:
            raise ConfigError(f"mapping.p_miss must be below 0.5 (a miss is evidence of free space), got {self.p_miss}")
        if not self.p_min < 0.5:
            raise ConfigError(f"mapping.p_min must be below 0.5 (a cell must be able to turn free), got {self.p_min}")
        if not self.p_max > 0.5:
            raise ConfigError(f"mapping.p_max must be above 0.5 (a cell must turn occupied), got {self.p_max}")

    @property
    def active(self) -> bool:
        """The occupancy is not the sticky default: the world runs its noisy path."""
        return self.occupancy != "sticky"

    def log_odds(self) -> tuple[float, float, float, float]:
        """``(l_hit, l_miss, l_min, l_max)``: the probabilities as log-odds ``log(p / (1 - p))``."""
        return tuple(math.log(p / (1.0 - p)) for p in (self.p_hit, self.p_miss, self.p_min, self.p_max))  # type: ignore[return-value]
