"""Tests for the goal planners (areasearch.planners): hand-built observations, properties, the env."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np
import pytest

from areasearch.envs.goal import AreaSearchEnv
from areasearch.errors import ConfigError
from areasearch.planners import (
    PLANNERS,
    CoScanPlanner,
    GoalPlanner,
    GreedyPlanner,
    HungarianPlanner,
    RandomPlanner,
    UtilityPlanner,
    VoronoiPlanner,
    make_planner,
)
from areasearch.planners.coscan import open_tour
from areasearch.planners.voronoi import voronoi_owner
from areasearch.sim.scene import bundled_index

F, T = 0, 1  # CandidateKind.FRONTIER, CandidateKind.TARGET
P_S_PLANNERS = (UtilityPlanner, VoronoiPlanner, CoScanPlanner)


def make_obs(
    distances: Sequence[Sequence[float]] | np.ndarray,
    kind: Sequence[int] | None = None,
    gain: Sequence[float] | None = None,
    cells: Sequence[Sequence[int]] | np.ndarray | None = None,
    action_mask: Sequence[Sequence[int]] | np.ndarray | None = None,
    pad: int = 0,
    pad_distance: float = np.inf,
) -> dict[str, np.ndarray]:
    """A valid observation of R robots and C real candidates (+ ``pad`` padded slots).

    Defaults: all frontiers of gain 1, candidate i at cell (0, 100 * i) (5 m apart at 0.05 m cells),
    every finite distance allowed. ``pad_distance`` fills the padded distances (+inf in the env; a
    finite value tests that padding is ignored through the masks alone).
    """
    dist = np.asarray(distances, dtype=np.float32)
    r, c = dist.shape
    total = c + pad
    candidates = np.zeros((total, 5), dtype=np.float32)
    default_cells = np.stack([np.zeros(c), 100.0 * np.arange(c)], axis=1)  # (C, 2)
    candidates[:c, 0:2] = np.asarray(cells, dtype=np.float32) if cells is not None else default_cells
    candidates[:c, 2] = kind if kind is not None else F
    candidates[:c, 3] = 1
    candidates[:c, 4] = gain if gain is not None else 1.0
    mask = np.zeros((r, total), dtype=np.int8)
    mask[:, :c] = np.asarray(action_mask, dtype=np.int8) if action_mask is not None else np.isfinite(dist)
    all_dist = np.full((r, total), pad_distance, dtype=np.float32)
    all_dist[:, :c] = dist
    h = 2
    return {
        "map": np.zeros((7, 8, 8), dtype=np.float32),
        "map_scale": np.array([4.0], dtype=np.float32),
        "robots": np.zeros((r, 3), dtype=np.float32),
        "candidates": candidates,
        "candidate_mask": (np.arange(total) < c).astype(np.int8),
        "distances": all_dist,
        "action_mask": mask,
        "history_robots": np.zeros((h, r, 2), dtype=np.float32),
        "history_goals": np.zeros((h, r, 2), dtype=np.float32),
        "history_mask": np.zeros(h, dtype=np.int8),
        "progress": np.zeros(1, dtype=np.float32),
    }


def random_obs(rng: np.random.Generator) -> dict[str, np.ndarray]:
    """A random observation: 1-5 robots, 0-12 candidates of both kinds, some unreachable, some masked."""
    r = int(rng.integers(1, 6))
    c = int(rng.integers(0, 13))
    dist = rng.uniform(0.1, 20.0, (r, c))
    dist[rng.random((r, c)) < 0.15] = np.inf
    mask = np.isfinite(dist) & (rng.random((r, c)) < 0.85)
    return make_obs(
        dist,
        kind=rng.integers(0, 2, c).tolist(),
        gain=rng.uniform(0, 500, c).tolist(),
        cells=rng.integers(0, 200, (c, 2)),
        action_mask=mask,
        pad=int(rng.integers(0, 4)),
        pad_distance=float(rng.choice([np.inf, 0.0])),
    )


def ready(planner: GoalPlanner, seed: int = 0) -> GoalPlanner:
    planner.reset(np.random.default_rng(seed))
    return planner


def all_planners() -> list[GoalPlanner]:
    return [make_planner(name) for name in PLANNERS]


# ---------------------------------------------------------------------------------- registry


def test_registry_builds_every_planner_under_its_name() -> None:
    assert {"random", "greedy", "utility", "utility-40", "utility-50", "utility-60", "voronoi", "coscan"} <= set(
        PLANNERS
    )
    for name in PLANNERS:
        planner = make_planner(name)
        assert isinstance(planner, GoalPlanner)
        assert planner.name == name
    assert [make_planner(f"utility-{p}").p_s for p in (40, 50, 60)] == [0.4, 0.5, 0.6]  # type: ignore[attr-defined]
    assert make_planner("utility").p_s == 0.6  # type: ignore[attr-defined]
    assert make_planner("utility", p_s=0.25).p_s == 0.25  # type: ignore[attr-defined]


def test_make_planner_rejects_unknown_names_and_settings() -> None:
    with pytest.raises(ConfigError, match=r"'nope'.*greedy"):
        make_planner("nope")
    with pytest.raises(ConfigError, match="utility"):
        make_planner("utility", lambda_=3)
    with pytest.raises(ConfigError, match="p_s"):
        make_planner("voronoi", p_s=1.5)
    with pytest.raises(ConfigError, match="cell_m"):
        make_planner("coscan", cell_m=0.0)


@pytest.mark.parametrize("planner", [RandomPlanner(), UtilityPlanner(), VoronoiPlanner(), CoScanPlanner()])
def test_randomised_planners_need_reset_first(planner: GoalPlanner) -> None:
    with pytest.raises(RuntimeError, match="reset"):
        planner.assign(make_obs([[1.0]]))


# ---------------------------------------------------------------------------------- properties


@pytest.mark.parametrize("name", list(PLANNERS))
def test_every_planner_returns_allowed_indices_and_leaves_obs_alone(name: str) -> None:
    planner = ready(make_planner(name))
    rng = np.random.default_rng(123)
    for _ in range(60):
        obs = random_obs(rng)
        before = {k: v.copy() for k, v in obs.items()}
        goals = planner.assign(obs)
        r = obs["action_mask"].shape[0]
        assert goals.shape == (r,) and goals.dtype == np.int64
        for robot, index in enumerate(goals):
            if obs["action_mask"][robot].any():
                assert obs["action_mask"][robot, index] == 1, (name, robot, index)
            else:
                assert index == 0
        for key, value in before.items():
            np.testing.assert_array_equal(obs[key], value, err_msg=f"{name} changed obs[{key!r}]")


@pytest.mark.parametrize("name", list(PLANNERS))
def test_same_seed_same_goals(name: str) -> None:
    observations = [random_obs(np.random.default_rng(s)) for s in range(25)]
    runs = []
    for _ in range(2):
        planner = ready(make_planner(name), seed=7)
        runs.append(np.concatenate([planner.assign(obs) for obs in observations]))
    np.testing.assert_array_equal(runs[0], runs[1])


@pytest.mark.parametrize("name", list(PLANNERS))
def test_masked_and_padded_candidates_are_never_chosen(name: str) -> None:
    # candidate 0 is the nearest for both robots but masked; padded slots read distance 0
    obs = make_obs(
        [[0.5, 3.0, 4.0], [0.5, 5.0, 2.0]],
        kind=[T, F, T],
        action_mask=[[0, 1, 1], [0, 1, 1]],
        pad=3,
        pad_distance=0.0,
    )
    planner = ready(make_planner(name))
    for _ in range(50):
        goals = planner.assign(obs)
        assert set(goals.tolist()) <= {1, 2}


@pytest.mark.parametrize("name", list(PLANNERS))
def test_a_robot_without_allowed_candidates_gets_index_zero(name: str) -> None:
    obs = make_obs([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]], kind=[F, T, F], action_mask=[[0, 0, 0], [0, 1, 1]], pad=2)
    goals = ready(make_planner(name)).assign(obs)
    assert goals[0] == 0 and goals[1] in (1, 2)
    empty = make_obs(np.zeros((3, 0)), pad=4)
    np.testing.assert_array_equal(ready(make_planner(name)).assign(empty), [0, 0, 0])


# ---------------------------------------------------------------------------------- random, greedy


def test_random_is_uniform_among_allowed_candidates() -> None:
    obs = make_obs([[1.0, 2.0, 3.0, 4.0, 5.0]], action_mask=[[1, 0, 1, 1, 0]], pad=2, pad_distance=0.0)
    planner = ready(RandomPlanner())
    draws = np.array([planner.assign(obs)[0] for _ in range(3000)])
    counts = np.bincount(draws, minlength=7)
    assert counts[[1, 4, 5, 6]].sum() == 0
    np.testing.assert_allclose(counts[[0, 2, 3]] / 3000, 1 / 3, atol=0.04)


def test_greedy_takes_each_robots_nearest_candidate_of_either_kind() -> None:
    obs = make_obs([[5.0, 2.0, 9.0], [1.0, 7.0, 3.0], [8.0, 6.0, np.inf]], kind=[F, T, F])
    np.testing.assert_array_equal(ready(GreedyPlanner()).assign(obs), [1, 0, 1])


# ---------------------------------------------------------------------------------- hungarian


def test_hungarian_matches_brute_force_on_3x4() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        dist = rng.uniform(1.0, 10.0, (3, 4))
        goals = ready(HungarianPlanner()).assign(make_obs(dist))
        best = min(sum(dist[r, c] for r, c in enumerate(p)) for p in itertools.permutations(range(4), 3))
        assert len(set(goals.tolist())) == 3
        assert dist[np.arange(3), goals].sum() == pytest.approx(best, rel=1e-6)


def test_hungarian_gives_distinct_goals_where_greedy_would_share() -> None:
    obs = make_obs([[1.0, 2.0], [1.5, 10.0]])
    np.testing.assert_array_equal(ready(GreedyPlanner()).assign(obs), [0, 0])
    np.testing.assert_array_equal(ready(HungarianPlanner()).assign(obs), [1, 0])


def test_hungarian_robots_beyond_the_candidates_take_their_nearest() -> None:
    obs = make_obs([[1.0, 4.0], [2.0, 3.0], [1.5, 9.0]])
    goals = ready(HungarianPlanner()).assign(obs)
    # {0: 0, 1: 1} costs 4.0, the least of every one-to-one pair; robot 2 then takes its nearest
    np.testing.assert_array_equal(goals, [0, 1, 0])


def test_hungarian_never_uses_a_forbidden_pair() -> None:
    obs = make_obs([[1.0, 2.0], [1.0, 2.0]], action_mask=[[1, 0], [1, 0]])
    np.testing.assert_array_equal(ready(HungarianPlanner()).assign(obs), [0, 0])


# ---------------------------------------------------------------------------------- voronoi


def test_voronoi_cells_follow_the_geodesic_distance() -> None:
    cost = np.array([[1.0, 2.0, 8.0, 9.0], [3.0, 1.5, 1.0, np.inf]])
    np.testing.assert_array_equal(voronoi_owner(cost), [0, 1, 1, 0])
    np.testing.assert_array_equal(voronoi_owner(np.full((2, 2), np.inf)), [-1, -1])


def test_voronoi_robot_takes_the_nearest_candidate_of_its_own_cell() -> None:
    # both robots are nearest to candidate 0, but it lies in robot 0's cell
    obs = make_obs([[1.0, 10.0], [2.0, 3.0]])
    np.testing.assert_array_equal(ready(GreedyPlanner()).assign(obs), [0, 0])
    np.testing.assert_array_equal(ready(VoronoiPlanner()).assign(obs), [0, 1])
    # a candidate robot 0 may not take belongs to the next nearest robot
    masked = make_obs([[1.0, 10.0], [2.0, 3.0]], action_mask=[[0, 1], [1, 1]])
    np.testing.assert_array_equal(ready(VoronoiPlanner()).assign(masked), [1, 0])


def test_voronoi_robot_with_an_empty_cell_falls_back_to_its_nearest() -> None:
    obs = make_obs([[1.0, 2.0, 3.0], [5.0, 6.0, 4.0]])
    np.testing.assert_array_equal(ready(VoronoiPlanner()).assign(obs), [0, 2])


def test_voronoi_weighs_the_kinds_of_its_own_cell_only() -> None:
    # robot 1's cell holds only frontier 2; the target 0 lies in robot 0's cell
    obs = make_obs([[1.0, 2.0, 9.0], [2.0, 9.0, 3.0]], kind=[T, F, F])
    np.testing.assert_array_equal(ready(VoronoiPlanner(p_s=1.0)).assign(obs), [0, 2])
    np.testing.assert_array_equal(ready(VoronoiPlanner(p_s=0.0)).assign(obs), [1, 2])
    # robot 1's cell holds only target 1: it takes it even with p_s = 0, not the nearer frontier 0
    obs = make_obs([[1.0, 9.0, 2.0], [2.0, 3.0, 9.0]], kind=[F, T, F])
    np.testing.assert_array_equal(ready(VoronoiPlanner(p_s=0.0)).assign(obs), [0, 1])


# ---------------------------------------------------------------------------------- coscan


def _tour_length(start: np.ndarray, between: np.ndarray, order: np.ndarray) -> float:
    if len(order) == 0:
        return 0.0
    return float(start[order[0]] + between[order[:-1], order[1:]].sum())


def test_open_tour_orders_points_on_a_line() -> None:
    x = np.array([3.0, 1.0, 2.0, 5.0])
    np.testing.assert_array_equal(open_tour(x, np.abs(x[:, None] - x[None, :])), [1, 2, 0, 3])


def test_open_tour_is_two_opt_optimal_and_no_longer_than_nearest_neighbour() -> None:
    rng = np.random.default_rng(4)
    improved = 0
    for _ in range(30):
        n = int(rng.integers(3, 9))
        pts = rng.uniform(0, 10, (n + 1, 2))  # row 0 is the start
        dist = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
        start, between = dist[0, 1:], dist[1:, 1:]
        order = open_tour(start, between)
        assert sorted(order.tolist()) == list(range(n))
        length = _tour_length(start, between, order)
        for i in range(n):
            for j in range(i + 1, n):
                flipped = np.concatenate([order[:i], order[i : j + 1][::-1], order[j + 1 :]])
                assert _tour_length(start, between, flipped) >= length - 1e-9
        nn = open_tour(start, between, max_moves=0)
        assert length <= _tour_length(start, between, nn) + 1e-9
        improved += length < _tour_length(start, between, nn) - 1e-9
        best = min(_tour_length(start, between, np.array(p)) for p in itertools.permutations(range(n)))
        assert length <= 1.25 * best
    assert improved > 0  # 2-opt did something on some instances


def test_coscan_shares_are_balanced_and_disjoint() -> None:
    # robot 0 is nearest to everything: unbalanced nearest choice would give it all six
    dist = np.array([[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], [10.0, 11.0, 12.0, 13.0, 14.0, 15.0]])
    tours = CoScanPlanner().tours(make_obs(dist, pad=2, pad_distance=0.0))
    assert [len(t) for t in tours] == [3, 3]
    assert sorted(np.concatenate(tours).tolist()) == list(range(6))
    rng = np.random.default_rng(5)
    for _ in range(30):
        obs = random_obs(rng)
        allowed = obs["action_mask"].astype(bool)
        active = int(allowed.any(axis=1).sum())
        count = int(allowed.any(axis=0).sum())
        tours = CoScanPlanner().tours(obs)
        flat = np.concatenate(tours) if tours else np.zeros(0, np.int64)
        assert len(set(flat.tolist())) == len(flat)  # disjoint
        for robot, tour in enumerate(tours):
            assert len(tour) <= math.ceil(count / max(active, 1))
            assert allowed[robot, tour].all()


def test_coscan_heads_for_the_first_goal_of_its_tour() -> None:
    # robot 0 at the start of a corridor of frontiers 0 m, 1 m, ... 5 m along (cells 20 apart);
    # robot 1 far away: each takes 3, robot 0 the near end, robot 1 the far end
    cells = [[0, 20 * i] for i in range(6)]
    dist = np.array([[0.5 + i for i in range(6)], [20.0 - i for i in range(6)]])
    planner = ready(CoScanPlanner(cell_m=0.05))
    obs = make_obs(dist, cells=cells)
    tours = planner.tours(obs)
    np.testing.assert_array_equal(tours[0], [0, 1, 2])
    np.testing.assert_array_equal(tours[1], [5, 4, 3])
    np.testing.assert_array_equal(planner.assign(obs), [0, 5])
    rng = np.random.default_rng(6)
    for _ in range(20):
        obs = random_obs(rng)
        obs["candidates"][:, 2] = F  # frontiers only: the p_s rule is out of play
        goals = planner.assign(obs)
        for robot, tour in enumerate(planner.tours(obs)):
            if len(tour):
                assert goals[robot] == tour[0]


# ---------------------------------------------------------------------------------- utility and p_s


def test_utility_trades_gain_against_distance() -> None:
    # frontier 0: gain 100 at 5 m; frontier 1: gain 50 at 1 m
    obs = make_obs([[5.0, 1.0]], gain=[100.0, 50.0])
    assert ready(UtilityPlanner(cost_weight_per_m=0.1)).assign(obs)[0] == 0  # 1 - 0.5 > 0.5 - 0.1
    assert ready(UtilityPlanner(cost_weight_per_m=1.0)).assign(obs)[0] == 1  # 1 - 5 < 0.5 - 1


def test_utility_discounts_frontiers_near_one_already_chosen() -> None:
    # two robots side by side; frontiers 0 and 1 are 0.05 m apart, frontier 2 is 10 m away from both
    cells = [[0, 0], [0, 1], [0, 200]]
    obs = make_obs([[1.0, 1.0, 2.0], [1.0, 1.0, 2.0]], gain=[100.0, 90.0, 80.0], cells=cells)
    np.testing.assert_array_equal(ready(UtilityPlanner()).assign(obs), [0, 2])
    # with a tiny discount radius only the chosen node itself loses its utility
    np.testing.assert_array_equal(ready(UtilityPlanner(discount_radius_m=0.01)).assign(obs), [0, 1])


def _p_s_extremes(planner_type: type, seed: int) -> list[tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]]:
    """(obs, goals with p_s = 1, goals with p_s = 0) on random observations with candidates."""
    rng = np.random.default_rng(seed)
    always, never = ready(planner_type(p_s=1.0)), ready(planner_type(p_s=0.0))
    out: list[tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]] = []
    while len(out) < 40:
        obs = random_obs(rng)
        if obs["candidate_mask"].any():
            out.append((obs, always.assign(obs), never.assign(obs)))
    return out


def test_utility_p_s_one_always_takes_a_target_and_zero_never() -> None:
    for obs, always, never in _p_s_extremes(UtilityPlanner, seed=8):
        allowed = obs["action_mask"].astype(bool)
        kind = obs["candidates"][:, 2]
        has_target = (allowed & (kind == T)).any(axis=1)
        has_frontier = (allowed & (kind == F)).any(axis=1)
        assert (kind[always][has_target] == T).all()
        assert (kind[never][has_frontier] == F).all()


def test_voronoi_p_s_extremes_within_the_robots_cell() -> None:
    for obs, always, never in _p_s_extremes(VoronoiPlanner, seed=9):
        allowed = obs["action_mask"].astype(bool)
        kind = obs["candidates"][:, 2]
        cost = np.where(allowed, obs["distances"], np.inf)
        own = allowed & (voronoi_owner(cost)[None, :] == np.arange(len(allowed))[:, None])  # (R, C)
        assert (kind[always][(own & (kind == T)).any(axis=1)] == T).all()
        assert (kind[never][(own & (kind == F)).any(axis=1)] == F).all()


def test_coscan_p_s_extremes() -> None:
    for obs, always, never in _p_s_extremes(CoScanPlanner, seed=10):
        allowed = obs["action_mask"].astype(bool)
        kind = obs["candidates"][:, 2]
        tours = CoScanPlanner().tours(obs)
        # p_s = 1: the first target of the tour, else the nearest allowed target
        assert (kind[always][(allowed & (kind == T)).any(axis=1)] == T).all()
        # p_s = 0: the first frontier of the tour whenever the tour holds one
        for robot, tour in enumerate(tours):
            frontiers = tour[kind[tour] == F]
            if len(frontiers):
                assert never[robot] == frontiers[0]


@pytest.mark.parametrize("planner_type", P_S_PLANNERS)
@pytest.mark.parametrize("p_s", [0.4, 0.6])
def test_targets_are_taken_with_frequency_p_s(planner_type: type, p_s: float) -> None:
    obs = make_obs([[1.0, 3.0, 2.0]], kind=[F, T, F])
    planner = ready(planner_type(p_s=p_s), seed=11)
    picks = np.array([planner.assign(obs)[0] for _ in range(4000)])
    assert set(np.unique(picks).tolist()) <= {0, 1}
    assert (picks == 1).mean() == pytest.approx(p_s, abs=0.035)  # 4.5 standard deviations


# ---------------------------------------------------------------------------------- in the environment


def _check_positions(env: AreaSearchEnv) -> None:
    poses = env.world.poses[:, :2]
    gaps = np.linalg.norm(poses[:, None] - poses[None], axis=-1)
    gaps[np.diag_indices(len(poses))] = np.inf
    assert gaps.min() >= 0.36, f"robots overlap: {gaps.min():.3f} m"
    scene = env.world.scene
    assert scene is not None
    cells = scene.world_to_cell(poses)
    assert scene.free[cells[:, 0], cells[:, 1]].all()


@pytest.mark.parametrize("name", list(PLANNERS))
def test_each_planner_drives_the_goal_env(name: str, small_map: str) -> None:
    env = AreaSearchEnv(map=small_map, num_robots=3, seed=0)
    obs, _ = env.reset(seed=0)
    planner = ready(make_planner(name))
    _check_positions(env)
    for _ in range(10):
        goals = planner.assign(obs)
        assert goals.shape == (3,) and goals.dtype == np.int64
        assert env.action_space.contains(goals)
        obs, _, terminated, truncated, info = env.step(goals)
        assert info["invalid_goals"] == 0
        _check_positions(env)
        if terminated or truncated:
            break


SMALL_MAPS = [entry["id"] for entry in bundled_index() if entry["size_class"] == "small"]


def test_there_are_26_small_maps() -> None:
    assert len(SMALL_MAPS) == 26


@pytest.mark.parametrize("map_id", SMALL_MAPS)
def test_greedy_explores_every_small_map(map_id: str) -> None:
    env = AreaSearchEnv(map=map_id, num_robots=3, seed=0)
    obs, _ = env.reset(seed=0)
    planner = ready(GreedyPlanner())
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(planner.assign(obs))
        done = terminated or truncated
    assert info["steps"] <= 3600
    assert info["explored_pct"] > 95.0, f"{map_id}: {info['explored_pct']:.1f} % explored"
