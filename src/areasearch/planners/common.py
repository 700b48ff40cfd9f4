"""Shared pieces of the goal planners: allowed costs, nearest choices, the p_s frontier/target pick.

Every planner reads the observation of :class:`areasearch.envs.goal.AreaSearchEnv` (R robots, C
candidate slots): ``action_mask`` (R, C) says which candidates a robot may choose, ``distances``
(R, C) are geodesic metres, ``candidates[:, 2]`` the :class:`areasearch.planning.candidates.CandidateKind`.
Nothing here mutates the observation.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..errors import ConfigError
from ..planning.candidates import CandidateKind

UNREACHABLE_M = 1e9
"""Cost, metres, given to an allowed candidate whose distance reads +inf (only in hand-built
observations: the environment allows only reachable candidates). It stays below +inf, so an allowed
candidate is always preferred to a forbidden one."""


def allowed_costs(obs: dict[str, np.ndarray]) -> np.ndarray:
    """(R, C) float64 geodesic metres where ``action_mask`` allows the candidate, +inf elsewhere."""
    allowed = np.asarray(obs["action_mask"]).astype(bool)  # (R, C)
    dist = np.asarray(obs["distances"], dtype=np.float64)  # (R, C)
    dist = np.nan_to_num(dist, nan=UNREACHABLE_M, posinf=UNREACHABLE_M)
    return np.where(allowed, dist, np.inf)


def kinds(obs: dict[str, np.ndarray]) -> np.ndarray:
    """(C,) int64 candidate kinds (0 frontier, 1 target)."""
    return np.asarray(obs["candidates"])[:, 2].astype(np.int64)


def nearest(cost: np.ndarray, where: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each robot's cheapest candidate among ``cost`` (R, C) entries that are finite (and ``where``
    (R, C) or (C,) holds). Returns ((R,) int64 indices, 0 where none; (R,) bool has one)."""
    if where is not None:
        cost = np.where(where, cost, np.inf)
    index = np.argmin(cost, axis=1).astype(np.int64) if cost.shape[1] else np.zeros(cost.shape[0], np.int64)
    has = np.isfinite(cost).any(axis=1)
    return np.where(has, index, 0), has


def nearest_allowed(obs: dict[str, np.ndarray]) -> np.ndarray:
    """(R,) int64: each robot's nearest allowed candidate, 0 for a robot with none."""
    return nearest(allowed_costs(obs))[0]


def pick_kind(
    frontier: np.ndarray,
    has_frontier: np.ndarray,
    target: np.ndarray,
    has_target: np.ndarray,
    fallback: np.ndarray,
    take_target: np.ndarray,
) -> np.ndarray:
    """The paper's p_s extension, vectorised over robots (all arguments (R,)): a robot with both a
    frontier and a target option takes the target where ``take_target`` (drawn with probability p_s),
    else the frontier; with one option it takes that one; with none, ``fallback``."""
    choose_target = has_target & (take_target | ~has_frontier)
    out = np.where(has_frontier, frontier, fallback)
    return np.where(choose_target, target, out).astype(np.int64)


def draw_targets(rng: np.random.Generator, robots: int, p_s: float) -> np.ndarray:
    """(R,) bool: for each robot, whether it takes its target option (probability ``p_s``). One
    uniform draw per robot per decision, whether or not it has both options."""
    return np.asarray(rng.random(robots) < p_s, dtype=bool)


def check_probability(name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and 0.0 <= value <= 1.0):
        raise ConfigError(f"{name} must be a probability in [0, 1], got {value!r}")


def check_positive(name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
        raise ConfigError(f"{name} must be a positive number, got {value!r}")


def check_non_negative(name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0):
        raise ConfigError(f"{name} must be a non-negative number, got {value!r}")


def require_rng(rng: np.random.Generator | None, name: str) -> np.random.Generator:
    if rng is None:
        raise RuntimeError(f"planner {name!r}: call reset(rng) before assign()")
    return rng


def balanced_assignment(cost: np.ndarray, capacity: int) -> np.ndarray:
    """Assign the columns of ``cost`` (R, K), +inf where forbidden, to rows, each row taking at most
    ``capacity`` columns: as many columns as the slots hold (all of them when R * capacity >= K), at
    minimum total cost. linear_sum_assignment on ``capacity`` replicated slots per row; a forbidden
    pair costs more than any set of allowed ones, and rows or columns with no allowed pair stay out.

    Returns (K,) int64: the row of each column, -1 for a column left unassigned.
    """
    k = cost.shape[1]
    owner = np.full(k, -1, dtype=np.int64)
    finite = np.isfinite(cost)
    rows_in = np.flatnonzero(finite.any(axis=1))  # robots with an allowed candidate
    cols_in = np.flatnonzero(finite.any(axis=0))  # candidates some robot may take
    if capacity <= 0 or rows_in.size == 0:
        return owner
    sub = cost[np.ix_(rows_in, cols_in)]  # (R', K')
    ok_sub = finite[np.ix_(rows_in, cols_in)]
    big = (float(sub[ok_sub].max()) + 1.0) * (cols_in.size + 1)
    slots = np.repeat(np.where(ok_sub, sub, big), capacity, axis=0)  # (R' * capacity, K')
    rows, cols = linear_sum_assignment(slots)
    robot = rows // capacity
    ok = ok_sub[robot, cols]
    owner[cols_in[cols[ok]]] = rows_in[robot[ok]]
    return owner


def kind_options(cost: np.ndarray, kind: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each robot's nearest frontier and nearest target within ``cost`` (R, C) (finite = eligible).
    Returns (frontier, has_frontier, target, has_target), each (R,)."""
    frontier, has_f = nearest(cost, kind == CandidateKind.FRONTIER)
    target, has_t = nearest(cost, kind == CandidateKind.TARGET)
    return frontier, has_f, target, has_t


def cell_size(obs: dict[str, np.ndarray], default: float) -> float:
    """The observation's cell size in metres (``obs["cell_m"]``), else ``default``."""
    return float(obs["cell_m"][0]) if "cell_m" in obs else default
