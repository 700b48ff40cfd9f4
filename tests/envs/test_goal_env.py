"""The high-level Gymnasium environment: API, spec, defined behaviour on bad goals, determinism."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import areasearch
from areasearch.envs.goal import MAP_CHANNELS, AreaSearchEnv, nearest_candidate
from areasearch.errors import ConfigError
from areasearch.planning.candidates import CandidateKind


def test_gymnasium_make_and_check_env(small_map: str) -> None:
    env = gymnasium.make(areasearch.GOAL_ENV_ID, map=small_map, num_robots=3)
    check_env(env.unwrapped)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert obs["map"].shape == (len(MAP_CHANNELS), 128, 128)


def test_a_decision_runs_forty_steps_and_sums_the_rewards() -> None:
    env = AreaSearchEnv(map="robotathome_sarmis", num_robots=3, seed=1)
    obs, _ = env.reset(seed=1)
    rewards: list[float] = []
    step = env.world.step

    def recording(actions: np.ndarray):  # type: ignore[no-untyped-def]
        result = step(actions)
        rewards.append(result.reward)
        return result

    env.world.step = recording  # type: ignore[method-assign]
    obs, reward, terminated, truncated, info = env.step(nearest_candidate(obs))
    assert info["steps"] == 40 and len(rewards) == 40
    assert reward == pytest.approx(sum(rewards))
    assert env.observation_space.contains(obs)
    assert not terminated and not truncated


def test_observation_follows_the_spec() -> None:
    env = AreaSearchEnv(map="robotathome_sarmis", num_robots=4, seed=2)
    obs, _ = env.reset(seed=2)
    for _ in range(3):
        obs, *_ = env.step(nearest_candidate(obs))
    cand = env.candidates
    k = len(cand)
    assert obs["candidate_mask"][:k].all() and not obs["candidate_mask"][k:].any()
    np.testing.assert_array_equal(obs["candidates"][:k, :2], cand.cells)
    np.testing.assert_array_equal(obs["candidates"][:k, 2], cand.kind)
    np.testing.assert_array_equal(obs["distances"][:, :k], cand.distance_m)
    assert np.isinf(obs["distances"][:, k:]).all()
    assert not obs["action_mask"][:, k:].any()
    assert (obs["action_mask"][:, :k] <= np.isfinite(cand.distance_m)).all()
    assert obs["history_mask"][:3].all() and not obs["history_mask"][3:].any()
    # map channels: explored share in [0, 1], obstacles and frontiers where the mapper has them
    scale = int(obs["map_scale"][0])
    explored = obs["map"][MAP_CHANNELS.index("explored")]
    assert 0 <= explored.min() and explored.max() <= 1
    mapped = env.world.mapper.occupied
    iy, ix = np.argwhere(mapped)[0]
    assert obs["map"][MAP_CHANNELS.index("obstacles"), iy // scale, ix // scale] == 1
    robots = obs["map"][MAP_CHANNELS.index("robots")]
    assert robots.sum() >= 1 and robots.sum() <= 4


def test_invalid_goals_fall_back_to_the_nearest_allowed_candidate() -> None:
    env = AreaSearchEnv(map="robotathome_sarmis", num_robots=3, seed=3)
    obs, _ = env.reset(seed=3)
    bad = np.array([10_000, -5, 0])
    masked = np.flatnonzero(obs["action_mask"][2] == 0)
    bad[2] = masked[0]  # a padded or unreachable slot
    expected = nearest_candidate(obs)
    cells = env.candidates.cells
    obs, _, _, _, info = env.step(bad)
    assert info["invalid_goals"] == 3
    np.testing.assert_array_equal(env._history[0][1], cells[expected].astype(np.float32))


def test_wrong_action_shape_is_a_config_error(small_map: str) -> None:
    env = AreaSearchEnv(map=small_map, num_robots=3, seed=0)
    env.reset(seed=0)
    with pytest.raises(ConfigError, match="one candidate index per robot"):
        env.step(np.array([0, 1]))


def test_an_episode_on_a_small_map_ends_with_everything_done(small_map: str) -> None:
    env = AreaSearchEnv(map=small_map, num_robots=3, seed=4)
    obs, _ = env.reset(seed=4)
    terminated = truncated = False
    while not (terminated or truncated):
        obs, _, terminated, truncated, info = env.step(nearest_candidate(obs))
    assert terminated
    assert info["explored_pct"] > 99.0 and info["covered_pct"] == 100.0
    assert info["reached_e"] and info["reached_c"] and info["time_e"] <= info["time_c"]


def test_nothing_left_to_explore_terminates_and_robots_get_no_goal(small_map: str) -> None:
    """A map already fully explored with every target covered: no candidate, no crash."""
    env = AreaSearchEnv(map=small_map, num_robots=2, seed=5, **{"targets.count": 0})
    obs, _ = env.reset(seed=5)
    env.world.mapper.explored[:] = True
    env.world.mapper.occupied[:] = ~env.world.scene.free
    env._refresh_candidates()
    obs = env._observation()
    assert not obs["candidate_mask"].any()
    obs, _, terminated, _, info = env.step(np.array([0, 0]))
    assert terminated and info["invalid_goals"] == 2
    assert (env.planner.goals == -1).all()


def test_target_goals_get_covered() -> None:
    env = AreaSearchEnv(map="robotathome_sarmis", num_robots=3, seed=6)
    obs, _ = env.reset(seed=6)
    covered_by_goal = 0
    for _ in range(15):
        kinds = obs["candidates"][:, 2]
        targets = (kinds == CandidateKind.TARGET) & obs["candidate_mask"].astype(bool)
        if targets.any():
            choice = np.where(obs["action_mask"].astype(bool) & targets, obs["distances"], np.inf).argmin(axis=1)
            before = env.world.covered.copy()
            ids = env.candidates.target_id[choice]
            obs, *_ = env.step(choice)
            covered_by_goal += int((env.world.covered & ~before)[ids[ids >= 0]].any())
        else:
            obs, *_ = env.step(nearest_candidate(obs))
    assert covered_by_goal >= 5


def test_same_seed_same_episode() -> None:
    def run() -> tuple[np.ndarray, float]:
        env = AreaSearchEnv(map="procedural:medium", num_robots=3)
        obs, _ = env.reset(seed=9)
        total = 0.0
        for _ in range(8):
            obs, reward, *_ = env.step(nearest_candidate(obs))
            total += reward
        return env.world.trajectory[: env.world.metrics.steps + 1].copy(), total

    (a, ra), (b, rb) = run(), run()
    assert np.array_equal(a, b) and ra == rb


def test_gymnasium_check_env_passes_with_all_noise_on(small_map: str) -> None:
    noise = {
        "noise.forward": 0.025,
        "noise.turn": 0.025,
        "noise.odometry_forward": 0.05,
        "noise.odometry_turn": 0.05,
        "noise.depth": 0.02,
        "noise.dropout": 0.1,
        "detection.model": "constant",
        "detection.p_near": 0.5,
    }
    env = gymnasium.make(areasearch.GOAL_ENV_ID, map=small_map, num_robots=3, **noise)
    check_env(env.unwrapped)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    for _ in range(3):
        obs, *_ = env.step(np.zeros(3, dtype=np.int64))
        assert env.observation_space.contains(obs)


def test_gymnasium_check_env_passes_with_limited_communication(small_map: str) -> None:
    env = AreaSearchEnv(map=small_map, num_robots=3, max_steps=200, **{"comm.model": "disc", "comm.range_m": 2.0})
    check_env(env)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    for _, group_obs in env.decision_groups():
        assert env.observation_space.contains(group_obs)
