"""Pipeline stage "planner": **Greedy**, the nearest-frontier strategy extended to area search.

Reference: the nearest-frontier approach of Visser et al. 2013 (DA-HGNN's ``visser2013discussion``,
"Baseline Methods"): each robot heads for its nearest frontier. As the paper does, the target nodes
(discovered, uncovered targets) join the frontier nodes in the set the robot chooses from: each
robot takes its nearest allowed candidate of either kind, by the observed geodesic (FMM) distance,
metres. No coordination between robots; deterministic (reset ignores the generator).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .common import nearest_allowed


@dataclass(eq=False)
class GreedyPlanner:
    """Each robot takes its nearest allowed frontier or target node."""

    name: str = "greedy"
    """Registry name, for reports."""

    def reset(self, rng: np.random.Generator) -> None:
        """Nothing to reset: the planner is deterministic."""

    def assign(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return nearest_allowed(obs)
