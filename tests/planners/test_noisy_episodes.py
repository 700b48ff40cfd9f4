"""Whole short episodes of goal planners in a world with every imperfection on: motion and odometry
noise (the planners read believed poses that drift from the true ones), depth noise and dropout, and
targets detected with a probability per frame."""

from __future__ import annotations

import numpy as np
import pytest

from areasearch.config import search_config
from areasearch.harness.evaluate import make_env, make_planner, planner_rng

ALL_NOISE = {
    "world.noise.forward": 0.025,
    "world.noise.turn": 0.025,
    "world.noise.odometry_forward": 0.05,
    "world.noise.odometry_turn": 0.05,
    "world.noise.depth": 0.02,
    "world.noise.dropout": 0.1,
    "world.detection.model": "linear",
    "world.detection.p_near": 0.9,
    "world.detection.p_far": 0.3,
}


@pytest.mark.parametrize("method", ["greedy", "dahgnn"])
def test_a_short_episode_runs_with_all_noise_on(method: str, small_map: str) -> None:
    env = make_env(small_map, 3, 0, 400, search_config(ALL_NOISE))
    planner = make_planner(method)
    obs, info = env.reset(seed=0)
    planner.reset(planner_rng(0))
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(planner.assign(obs))
        done = terminated or truncated
    world = env.world
    assert world.metrics.steps > 0 and world.noise is not None
    assert 0 < info["explored_pct"] <= 100
    assert world.metrics.covered <= world.metrics.discovered
    assert not np.array_equal(world.believed_poses, world.poses)
