"""Whole short episodes of every classical goal planner and DA-HGNN under limited communication: the team
splits into groups that each decide from their own map (areasearch.envs.goal.decide), five robots."""

from __future__ import annotations

import numpy as np
import pytest

from areasearch.config import search_config
from areasearch.envs.goal import decide
from areasearch.harness.episodes import play_episode
from areasearch.harness.evaluate import make_env, make_planner, planner_rng

COMM = {
    "disc": {"world.comm.model": "disc", "world.comm.range_m": 2.0},
    "signal": {"world.comm.model": "signal"},
}
METHODS = ["random", "greedy", "utility", "hungarian", "coscan", "voronoi", "dahgnn"]


@pytest.mark.parametrize("model", sorted(COMM))
@pytest.mark.parametrize("method", METHODS)
def test_a_short_episode_runs_under_limited_communication(method: str, model: str, small_map: str) -> None:
    env = make_env(small_map, 5, 0, 200, search_config(COMM[model]))
    trace = play_episode(env, make_planner(method), 0)
    world = env.world
    assert world.knowledge is not None and world.metrics.steps > 0
    assert 0 < trace.info["explored_pct"] <= 100
    assert world.metrics.covered <= world.metrics.discovered
    assert sorted(int(r) for group in world.comm_groups for r in group) == list(range(5))


def test_each_group_decides_from_its_own_observation(small_map: str) -> None:
    env = make_env(small_map, 5, 0, 200, search_config({"world.comm.model": "disc", "world.comm.range_m": 0.5}))
    obs, _ = env.reset(seed=0)
    groups = env.decision_groups()
    assert len(groups) > 1 and groups[0][1] is obs
    world = env.world
    for robots, group_obs in groups:
        assert env.observation_space.contains(group_obs)
        mine = world.robot_maps[int(robots[0])]
        assert mine is not world.mapper
        others = np.setdiff1d(np.arange(5), robots)
        heard = world.team_poses(int(robots[0]))
        np.testing.assert_array_equal(heard[robots], world.believed_poses[robots])
        np.testing.assert_array_equal(heard[others], world.believed_trajectory[0, others])  # never heard: the start
    planner = make_planner("greedy")
    planner.reset(planner_rng(0))
    calls: list[int] = []

    def assign(group_obs: dict[str, np.ndarray]) -> np.ndarray:
        calls.append(1)
        return planner.assign(group_obs)

    action = decide(env, assign)
    assert len(calls) == len(groups) and action.shape == (5,)
    env.step(action)
