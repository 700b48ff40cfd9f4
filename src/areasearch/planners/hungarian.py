"""Pipeline stage "planner": **Hungarian**, the minimum-total-distance one-to-one assignment.

Robots and candidates (frontier and target nodes alike) form a bipartite graph weighted by the
observed geodesic (FMM) distance, metres; :func:`scipy.optimize.linear_sum_assignment` (the Hungarian
method) gives each robot a distinct candidate so that the summed distance is minimal. A forbidden
pair (``action_mask`` 0, or +inf distance) costs more than any set of allowed pairs, so it is used only
where nothing else fits, and then replaced. Robots left without a candidate (fewer allowed candidates
than robots, or only forbidden ones left) take their nearest allowed candidate, possibly shared.
Deterministic (reset ignores the generator).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .common import allowed_costs, balanced_assignment, nearest


@dataclass(eq=False)
class HungarianPlanner:
    """One distinct candidate per robot, minimising the team's total geodesic distance."""

    name: str = "hungarian"
    """Registry name, for reports."""

    def reset(self, rng: np.random.Generator) -> None:
        """Nothing to reset: the planner is deterministic."""

    def assign(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        cost = allowed_costs(obs)  # (R, C)
        out, _ = nearest(cost)
        owner = balanced_assignment(cost, capacity=1)  # (C,)
        cols = np.flatnonzero(owner >= 0)
        out[owner[cols]] = cols
        return out
