"""Pipeline stage "planner": **Random**, the sanity floor.

Each robot takes a candidate drawn uniformly among the ones its ``action_mask`` row allows
(frontier and target nodes alike); a robot with none gets index 0 (the environment then gives it no
goal). All randomness comes from the generator given to :meth:`RandomPlanner.reset`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .common import require_rng


@dataclass(eq=False)
class RandomPlanner:
    """Uniform choice among each robot's allowed candidates."""

    name: str = "random"
    """Registry name, for reports."""
    _rng: np.random.Generator | None = field(default=None, init=False, repr=False)

    def reset(self, rng: np.random.Generator) -> None:
        self._rng = rng

    def assign(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        rng = require_rng(self._rng, self.name)
        allowed = np.asarray(obs["action_mask"]).astype(bool)  # (R, C)
        # The argmax of i.i.d. uniform scores over the allowed entries is a uniform draw among them.
        scores = np.where(allowed, rng.random(allowed.shape), -1.0)  # (R, C)
        index = np.argmax(scores, axis=1).astype(np.int64)
        return np.where(allowed.any(axis=1), index, 0)
