"""Pipeline stage "planner": **Utility**, the coordinated utility-maximising frontier assignment,
extended to area search with the paper's p_s rule.

Reference: M. Julia, A. Gil, O. Reinoso, "A comparison of path planning strategies for autonomous
exploration and mapping of unknown environments", Autonomous Robots 33 (2012): the utility method
(after Burgard et al. 2005) scores a frontier for a robot by its information gain minus lambda times
the path cost, and coordinates the team by assigning robots one at a time, each assignment lowering
the utility of the frontiers near the chosen one for the robots that follow.

Here, per decision:

* **Frontier option** (coordinated). Gain is ``candidates[:, 4]`` (unknown cells within sensor range
  of the node), normalised by the largest gain among the frontier nodes offered this decision, so
  utility U lies in [0, 1] whatever the map's resolution; the score of frontier j for robot r is
  ``U_j - cost_weight_per_m * d_rj`` with d the observed geodesic distance, metres. Burgard's greedy
  sequence: the (robot, frontier) pair of highest score is fixed, then every frontier's utility is
  scaled by ``min(1, e / discount_radius_m)`` (e its Euclidean distance to the chosen node: the share
  of its gain not expected to be seen from there, Burgard's linear visibility model), and so on for
  the robots left. The chosen node itself drops to utility 0.
* **Target option**: the robot's nearest allowed target node.
* **Choice** (DA-HGNN, "Impact Analysis of Probability Setting"): with both options a robot takes the
  target with probability ``p_s``, else the frontier; with one kind only, that one. The coin is drawn
  before the frontier sequence, so robots bound for targets do not discount frontiers.

Registered as ``utility`` (p_s 0.6, the paper's main setting) and ``utility-40``, ``utility-50``,
``utility-60`` (the variants of the paper's Table 7).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..planning.candidates import CandidateKind
from .common import (
    allowed_costs,
    cell_size,
    check_non_negative,
    check_positive,
    check_probability,
    draw_targets,
    kinds,
    nearest,
    pick_kind,
    require_rng,
)


@dataclass(eq=False)
class UtilityPlanner:
    """Julia et al.'s coordinated utility method over frontiers, the nearest target with probability p_s."""

    p_s: float = 0.6
    """Probability that a robot with both a frontier and a target option takes the target (paper: 0.6;
    Table 7 compares 0.4, 0.5, 0.6)."""
    cost_weight_per_m: float = 0.1
    """lambda, per metre: the weight of the path cost against the normalised gain. At 0.1 a frontier
    10 m farther (the most a robot drives in one 40-step decision, at 0.25 m per step) must offer the
    whole best gain more to be preferred: gain decides among nearby frontiers, distance beyond."""
    discount_radius_m: float = 3.2
    """Frontiers closer than this to a frontier already chosen lose utility in proportion to the
    closeness, metres (default: the depth camera's range, ``camera.max_range_m``)."""
    cell_m: float = 0.05
    """Map cell size, metres, to turn candidate cells into metres when the observation does not carry
    it (``obs["cell_m"]``, which the environment provides, wins)."""
    name: str = "utility"
    """Registry name, for reports."""
    _rng: np.random.Generator | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        check_probability("p_s", self.p_s)
        check_non_negative("cost_weight_per_m", self.cost_weight_per_m)
        check_positive("discount_radius_m", self.discount_radius_m)
        check_positive("cell_m", self.cell_m)

    def reset(self, rng: np.random.Generator) -> None:
        self._rng = rng

    def assign(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        rng = require_rng(self._rng, self.name)
        cost = allowed_costs(obs)  # (R, C)
        kind = kinds(obs)  # (C,)
        take_target = draw_targets(rng, cost.shape[0], self.p_s)  # (R,)
        target, has_target = nearest(cost, kind == CandidateKind.TARGET)
        frontier_cost = np.where(kind == CandidateKind.FRONTIER, cost, np.inf)  # (R, C)
        has_frontier = np.asarray(np.isfinite(frontier_cost).any(axis=1))
        explorers = has_frontier & ~(has_target & take_target)
        frontier = self._frontiers(obs, frontier_cost, explorers)
        return pick_kind(frontier, has_frontier, target, has_target, nearest(cost)[0], take_target)

    def _frontiers(self, obs: dict[str, np.ndarray], cost: np.ndarray, explorers: np.ndarray) -> np.ndarray:
        """(R,) int64: the frontier of each robot in ``explorers`` by the coordinated utility sequence
        (0 for the others). ``cost`` (R, C) is finite exactly on each robot's allowed frontiers."""
        out = np.zeros(cost.shape[0], dtype=np.int64)
        cols = np.flatnonzero(np.isfinite(cost[explorers]).any(axis=0))  # (K,) frontiers in play
        if cols.size == 0:
            return out
        cand = np.asarray(obs["candidates"], dtype=np.float64)
        gain = np.maximum(cand[cols, 4], 0.0)  # (K,)
        top = gain.max()
        utility = gain / top if top > 0 else np.zeros_like(gain)  # (K,) in [0, 1]
        cells_m = cand[cols, :2] * cell_size(obs, self.cell_m)  # (K, 2)
        penalty = self.cost_weight_per_m * cost[:, cols]  # (R, K), +inf where not allowed
        left = explorers.copy()
        while left.any():
            score = np.where(left[:, None], utility[None, :] - penalty, -np.inf)  # (R, K)
            r, j = np.unravel_index(int(np.argmax(score)), score.shape)
            out[r] = cols[j]
            left[r] = False
            seen = np.hypot(*(cells_m - cells_m[j]).T)  # (K,) metres to the chosen node
            utility = utility * np.minimum(1.0, seen / self.discount_radius_m)
        return out
