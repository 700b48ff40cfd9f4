"""Pipeline stage "planner": **CoScan**, balanced optimal-transport assignment plus a TSP tour per
robot, extended to area search with the paper's p_s rule.

Reference: S. Dong, K. Xu, Q. Zhou, A. Tagliasacchi, S. Xin, M. Niessner, B. Chen, "Multi-robot
collaborative dense scene reconstruction", ACM TOG 38(4) (SIGGRAPH 2019): the scan tasks are
distributed among the robots by an optimal mass transport with equal capacities, then each robot
visits its share along a travelling-salesman tour.

Here, per decision:

* **Balanced assignment** (the discrete transport): the K candidates some robot may take (frontier and
  target nodes alike) go to the R' robots that have one, each robot taking at most ceil(K / R') of
  them (ceil(C / R) when every robot may take something), at minimum total geodesic distance:
  :func:`scipy.optimize.linear_sum_assignment` on ceil(K / R') replicated slots per robot.
* **Tour**: each robot orders its share by an open TSP path that starts at the robot: nearest
  neighbour, then 2-opt (best improving segment reversal until none is left, at most
  ``max_two_opt_moves``). Robot-to-candidate legs use the observed geodesic distance; only those are
  observed, so candidate-to-candidate legs are the Euclidean distance between the candidate cells
  times ``cell_m`` (a lower bound of the geodesic one).
* **Choice**: the frontier option is the first frontier node of the tour; the target option the
  first target node of the tour, or the robot's nearest allowed target if its tour has none. With
  both, the robot takes the target with probability ``p_s`` (DA-HGNN, "Impact Analysis of Probability
  Setting"), else the frontier; with one kind only, that one. A robot with an empty share (K < R')
  takes its nearest allowed candidate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..planning.candidates import CandidateKind
from .common import (
    allowed_costs,
    balanced_assignment,
    cell_size,
    check_positive,
    check_probability,
    draw_targets,
    kinds,
    nearest,
    pick_kind,
    require_rng,
)


def open_tour(start_m: np.ndarray, between_m: np.ndarray, max_moves: int = 1000) -> np.ndarray:
    """Order n points along a short open path that starts at a fixed start (the robot).

    ``start_m`` (n,) start-to-point lengths, ``between_m`` (n, n) symmetric point-to-point lengths.
    Nearest neighbour from the start, then 2-opt: the best improving reversal of a segment, the path's
    free end included, until no reversal shortens it (or ``max_moves`` reversals). Returns (n,) int64.
    """
    n = start_m.shape[0]
    if n <= 1:
        return np.arange(n, dtype=np.int64)
    # nodes: 0 start, 1..n points, n + 1 the free end (zero length to everything)
    d = np.zeros((n + 2, n + 2))
    d[1 : n + 1, 1 : n + 1] = between_m
    d[0, 1 : n + 1] = start_m
    d[1 : n + 1, 0] = start_m
    path = np.empty(n + 2, dtype=np.int64)
    path[0], path[-1] = 0, n + 1
    todo = np.ones(n + 2, dtype=bool)
    todo[[0, n + 1]] = False
    for k in range(1, n + 1):
        nxt = int(np.argmin(np.where(todo, d[path[k - 1]], np.inf)))
        path[k] = nxt
        todo[nxt] = False
    upper = np.triu(np.ones((n, n), dtype=bool), k=1)  # reversal of path[i..j], 1 <= i < j <= n
    for _ in range(max_moves):
        a, b = path[:n], path[1 : n + 1]  # (n,) edges (path[i-1], path[i]), i = 1..n
        c, e = path[1 : n + 1], path[2 : n + 2]  # (n,) edges (path[j], path[j+1]), j = 1..n
        delta = d[a[:, None], c[None, :]] + d[b[:, None], e[None, :]] - d[a, b][:, None] - d[c, e][None, :]  # (n, n)
        delta = np.where(upper, delta, 0.0)
        best = int(np.argmin(delta))
        if delta.flat[best] >= -1e-9:
            break
        i, j = divmod(best, n)
        path[i + 1 : j + 2] = path[i + 1 : j + 2][::-1].copy()
    return path[1 : n + 1] - 1


@dataclass(eq=False)
class CoScanPlanner:
    """Balanced assignment of the candidates to the robots, each robot heading along its TSP tour."""

    p_s: float = 0.6
    """Probability that a robot with both a frontier and a target option takes the target (paper: 0.6)."""
    cell_m: float = 0.05
    """Map cell size, metres, for the candidate-to-candidate legs when the observation does not carry
    it (``obs["cell_m"]``, which the environment provides, wins)."""
    max_two_opt_moves: int = 1000
    """Most 2-opt reversals per tour (a safety cap; tours of a few dozen nodes settle far sooner)."""
    name: str = "coscan"
    """Registry name, for reports."""
    _rng: np.random.Generator | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        check_probability("p_s", self.p_s)
        check_positive("cell_m", self.cell_m)
        check_positive("max_two_opt_moves", self.max_two_opt_moves)

    def reset(self, rng: np.random.Generator) -> None:
        self._rng = rng

    def tours(self, obs: dict[str, np.ndarray]) -> list[np.ndarray]:
        """Each robot's share of the candidates, as (n_r,) int64 candidate indices in tour order."""
        cost = allowed_costs(obs)  # (R, C)
        finite = np.isfinite(cost)
        robots = int(finite.any(axis=1).sum())
        count = int(finite.any(axis=0).sum())
        capacity = math.ceil(count / robots) if robots else 0
        owner = balanced_assignment(cost, capacity)  # (C,)
        cells_m = np.asarray(obs["candidates"], dtype=np.float64)[:, :2] * cell_size(obs, self.cell_m)  # (C, 2)
        tours = []
        for r in range(cost.shape[0]):
            mine = np.flatnonzero(owner == r)  # (n,)
            between = np.linalg.norm(cells_m[mine, None, :] - cells_m[None, mine, :], axis=-1)  # (n, n)
            tours.append(mine[open_tour(cost[r, mine], between, self.max_two_opt_moves)])
        return tours

    def assign(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        rng = require_rng(self._rng, self.name)
        cost = allowed_costs(obs)  # (R, C)
        kind = kinds(obs)  # (C,)
        n = cost.shape[0]
        take_target = draw_targets(rng, n, self.p_s)  # (R,)
        target, has_target = nearest(cost, kind == CandidateKind.TARGET)
        frontier = np.zeros(n, dtype=np.int64)
        has_frontier = np.zeros(n, dtype=bool)
        for r, tour in enumerate(self.tours(obs)):
            is_frontier = kind[tour] == CandidateKind.FRONTIER
            if is_frontier.any():
                frontier[r], has_frontier[r] = tour[np.argmax(is_frontier)], True
            if (~is_frontier).any():
                target[r], has_target[r] = tour[np.argmax(~is_frontier)], True
        return pick_kind(frontier, has_frontier, target, has_target, nearest(cost)[0], take_target)
