"""Pipeline stage "planner": **Voronoi**, goals from the geodesic Voronoi partition of the known
space, extended to area search with the paper's p_s rule.

Reference: S. Bhattacharya, R. Ghrist, V. Kumar, "Multi-robot coverage and exploration on Riemannian
manifolds with boundaries", IJRR 2014 (DA-HGNN's ``bhattacharya2014multi``): the free space known so
far is split into geodesic Voronoi cells, one per robot, and each robot explores the frontier of its
own cell.

Here the observed ``distances`` are Fast Marching geodesics from each robot over the planning grid,
so a candidate lies in robot r's geodesic Voronoi cell exactly when r is its geodesically nearest
robot; only robots allowed to take the candidate (``action_mask``) compete for it, ties go to the
lower robot index. Each robot's frontier option is the nearest frontier node of its own cell, its
target option the nearest target node of its own cell; with both it takes the target with
probability ``p_s`` (DA-HGNN, "Impact Analysis of Probability Setting"), else the frontier; with one
kind only, that one. A robot whose cell holds no candidate takes its nearest allowed candidate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .common import allowed_costs, check_probability, draw_targets, kind_options, kinds, nearest, pick_kind, require_rng


def voronoi_owner(cost: np.ndarray) -> np.ndarray:
    """(C,) int64: the robot with the smallest finite ``cost`` (R, C) to each candidate, -1 where none."""
    if cost.shape[0] == 0:
        return np.full(cost.shape[1], -1, dtype=np.int64)
    owner = np.argmin(cost, axis=0).astype(np.int64)
    return np.where(np.isfinite(cost).any(axis=0), owner, -1)


@dataclass(eq=False)
class VoronoiPlanner:
    """Each robot takes the nearest candidate of its own geodesic Voronoi cell (p_s between kinds)."""

    p_s: float = 0.6
    """Probability that a robot with both a frontier and a target option takes the target (paper: 0.6)."""
    name: str = "voronoi"
    """Registry name, for reports."""
    _rng: np.random.Generator | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        check_probability("p_s", self.p_s)

    def reset(self, rng: np.random.Generator) -> None:
        self._rng = rng

    def assign(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        rng = require_rng(self._rng, self.name)
        cost = allowed_costs(obs)  # (R, C)
        take_target = draw_targets(rng, cost.shape[0], self.p_s)  # (R,)
        owner = voronoi_owner(cost)  # (C,)
        own = owner[None, :] == np.arange(cost.shape[0])[:, None]  # (R, C) the robot's Voronoi cell
        frontier, has_f, target, has_t = kind_options(np.where(own, cost, np.inf), kinds(obs))
        return pick_kind(frontier, has_f, target, has_t, nearest(cost)[0], take_target)
