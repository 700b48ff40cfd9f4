"""The PettingZoo environment: API conformance, spec, determinism."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test

import areasearch
from areasearch.errors import ConfigError, MapError


def test_parallel_api_test_passes(small_map: str) -> None:
    env = areasearch.parallel_env(map=small_map, num_robots=3, seed=0, max_steps=120)
    parallel_api_test(env, num_cycles=200)


def test_aec_api_test_passes(small_map: str) -> None:
    env = areasearch.env(map=small_map, num_robots=2, seed=0, max_steps=60)
    api_test(env, num_cycles=100)


def test_observations_rewards_and_infos_follow_the_spec(small_map: str) -> None:
    env = areasearch.parallel_env(map=small_map, num_robots=3, seed=1, max_steps=50)
    obs, infos = env.reset(seed=1)
    assert env.agents == ["robot_0", "robot_1", "robot_2"]
    for agent in env.agents:
        assert env.observation_space(agent).contains(obs[agent])
        assert env.action_space(agent).n == 4
        assert set(infos[agent]) >= {"collided", "explored_pct", "covered_pct", "time_e", "time_c"}
    rng = np.random.default_rng(0)
    for _ in range(49):
        obs, rewards, _, truncs, infos = env.step({a: int(rng.integers(4)) for a in env.agents})
        assert len(set(rewards.values())) == 1  # one team reward
        assert not any(truncs.values())
        for agent in env.agents:
            assert env.observation_space(agent).contains(obs[agent])
        np.testing.assert_allclose(obs["robot_0"]["pose"], env.world.poses[0], rtol=1e-6)
    *_, truncs, _ = env.step({a: 3 for a in env.agents})
    assert all(truncs.values()) and env.agents == []
    with pytest.raises(RuntimeError):
        env.step({})


def test_local_map_is_the_merged_map_around_the_robot(small_map: str) -> None:
    env = areasearch.parallel_env(map=small_map, num_robots=2, seed=2, local_map_cells=21)
    obs, _ = env.reset(seed=2)
    world = env.world
    iy, ix = world.scene.world_to_cell(world.poses[1, :2])
    window = obs["robot_1"]["local_map"]
    assert window.shape == (3, 21, 21)
    assert window[0, 10, 10] == world.mapper.explored[iy, ix]
    np.testing.assert_array_equal(window[1, 5:16, 5:16], world.mapper.occupied[iy - 5 : iy + 6, ix - 5 : ix + 6])
    assert np.array_equal(env.state(), world.mapper.channels())


def test_terminates_when_everything_is_explored_and_covered(small_map: str) -> None:
    env = areasearch.parallel_env(
        map=small_map,
        num_robots=4,
        seed=0,
        max_steps=3000,
        protocol="passby",
        **{"targets.count": 3, "targets.cover_radius_m": 1.5},
    )
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    terms = {}
    for _ in range(3000):
        _, _, terms, truncs, _ = env.step({a: int(rng.choice(3, p=[0.6, 0.2, 0.2])) for a in env.agents})
        if not env.agents:
            break
    assert all(terms.values()) and not any(truncs.values())
    assert env.world.all_explored and env.world.covered.all()


def test_same_seed_same_episode() -> None:
    def run() -> list[np.ndarray]:
        env = areasearch.parallel_env(map="procedural:small", num_robots=3, max_steps=100)
        obs, _ = env.reset(seed=42)
        rng = np.random.default_rng(1)
        frames = [obs["robot_2"]["depth"]]
        for _ in range(60):
            obs, *_ = env.step({a: int(rng.integers(4)) for a in env.agents})
            frames.append(obs["robot_2"]["depth"])
        frames.append(env.state())
        return frames

    for a, b in zip(run(), run(), strict=True):
        assert np.array_equal(a, b)


def test_map_folder_draws_a_map_per_reset(tmp_path) -> None:
    env = areasearch.parallel_env(map=str(areasearch.sim.scene.bundled_maps_dir()), num_robots=3)
    names = set()
    for seed in range(6):
        env.reset(seed=seed)
        names.add(env.world.scene.name)
    assert len(names) >= 3


def test_render_rgb_array(small_map: str) -> None:
    env = areasearch.parallel_env(map=small_map, num_robots=3, seed=0, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    assert areasearch.parallel_env(map=small_map).render() is None


def test_bad_arguments_raise_specific_errors(small_map: str) -> None:
    with pytest.raises(MapError):
        areasearch.parallel_env(map="does/not/exist.yaml")
    with pytest.raises(ConfigError, match="num_robots"):
        areasearch.parallel_env(map=small_map, num_robots=0)
    with pytest.raises(ConfigError, match="unknown setting"):
        areasearch.parallel_env(map=small_map, colour="red")
    with pytest.raises(ConfigError, match="render_mode"):
        areasearch.parallel_env(map=small_map, render_mode="human")
    env = areasearch.parallel_env(map=small_map, num_robots=2)
    env.reset(seed=0)
    with pytest.raises(ConfigError, match="agent"):
        env.step({"robot_7": 0})


def test_observations_of_one_step_are_not_written_again() -> None:
    """Each robot's observation is a view of one fresh array per field and step: what a step
    handed out stays as it was after the next step."""
    env = areasearch.parallel_env(map="wrs2020_arena", num_robots=3, seed=0)
    obs, _ = env.reset(seed=0)
    kept = {a: {k: v.copy() for k, v in o.items()} for a, o in obs.items()}
    for _ in range(5):
        env.step(dict.fromkeys(env.agents, 0))
    for agent, fields in kept.items():
        for key, value in fields.items():
            np.testing.assert_array_equal(obs[agent][key], value)


NOISE = {
    "noise__forward": 0.025,
    "noise__turn": 0.025,
    "noise__odometry_forward": 0.05,
    "noise__odometry_turn": 0.05,
    "noise__depth": 0.02,
    "noise__dropout": 0.1,
    "detection__model": "linear",
    "detection__p_near": 0.9,
    "detection__p_far": 0.3,
}


def test_parallel_api_test_passes_with_all_noise_on(small_map: str) -> None:
    env = areasearch.parallel_env(map=small_map, num_robots=3, seed=0, max_steps=120, **NOISE)
    parallel_api_test(env, num_cycles=200)
    obs, _ = env.reset(seed=0)
    np.testing.assert_array_equal(obs["robot_0"]["pose"], env.world.believed_poses[0].astype(np.float32))


def test_parallel_api_test_passes_with_limited_communication(small_map: str) -> None:
    env = areasearch.parallel_env(map=small_map, num_robots=3, seed=0, max_steps=120, **{"comm.model": "disc"})
    parallel_api_test(env, num_cycles=200)
    assert env.world.knowledge is not None
