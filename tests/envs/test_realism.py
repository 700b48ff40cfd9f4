"""The realism presets (:mod:`areasearch.config.realism`): each preset's values reach the world's
configuration, ``none`` is the default world bit for bit, explicit settings win over a preset, an unknown
name is refused naming the valid ones, and both environments take ``realism=``."""

from __future__ import annotations

import hashlib

import gymnasium
import numpy as np
import pytest

import areasearch
from areasearch.config import (
    REALISM_NAMES,
    REALISM_PRESETS,
    NoiseConfig,
    SearchConfig,
    WorldConfig,
    realism_config,
    realism_keywords,
    realism_settings,
)
from areasearch.envs.goal import AreaSearchEnv
from areasearch.errors import ConfigError
from areasearch.harness.evaluate import make_env, make_planner, play_episode

EXPECTED = {
    "low": {
        "noise": NoiseConfig(0.025, 0.025, 0.005, 0.005, 0.005, 0.01),
        "detection": ("constant", 0.95, 1.0),
        "comm": ("disc", 10.0, -20.0),
    },
    "medium": {
        "noise": NoiseConfig(0.05, 0.05, 0.01, 0.01, 0.01, 0.05),
        "detection": ("linear", 0.95, 0.6),
        "comm": ("signal", 3.6, -20.0),
    },
    "high": {
        "noise": NoiseConfig(0.1, 0.1, 0.02, 0.02, 0.02, 0.1),
        "detection": ("linear", 0.9, 0.3),
        "comm": ("signal", 3.6, -25.0),
    },
}
"""Each preset's world as the brief states it (comm: model, range_m, tx_power_dbm)."""


def _world_summary(world: WorldConfig) -> dict[str, object]:
    d, c = world.detection, world.comm
    return {
        "noise": world.noise,
        "detection": (d.model, d.p_near, d.p_far),
        "comm": (c.model, c.range_m, c.tx_power_dbm),
    }


def test_the_presets_are_named_from_none_to_high() -> None:
    assert REALISM_NAMES == ("none", "low", "medium", "high")
    assert dict(REALISM_PRESETS["none"]) == {}
    for name in REALISM_NAMES:  # every key a full --set key of the world
        assert all(key.startswith("world.") for key in REALISM_PRESETS[name]), name


@pytest.mark.parametrize("name", ["low", "medium", "high"])
def test_each_preset_reaches_the_world_config(name: str) -> None:
    config = realism_config(name)
    assert _world_summary(config.world) == EXPECTED[name]
    assert config.world.imperfect
    others = {field: getattr(config.world, field) for field in ("robot", "camera", "targets", "reward", "protocol")}
    assert others == {field: getattr(WorldConfig(), field) for field in others}  # nothing else set
    if name != "low":  # IR2's signal model: the CommConfig defaults but for the transmit power
        default = WorldConfig().comm
        assert config.world.comm.threshold_dbm == default.threshold_dbm
        assert config.world.comm.shadowing_max_db == default.shadowing_max_db


def test_none_is_the_default_world() -> None:
    assert realism_config("none") == SearchConfig()
    assert realism_settings("none", {"targets.count": 5}) == {"world.targets.count": 5}
    assert realism_keywords("none", {"noise__forward": 0.1}) == {"noise__forward": 0.1}


@pytest.mark.parametrize("key", ["noise.forward", "world.noise.forward", "noise__forward"])
def test_an_explicit_setting_wins_over_the_preset(key: str) -> None:
    settings = realism_settings("medium", {key: 0.2, "comm.model": "full"})
    assert settings["world.noise.forward"] == 0.2 and settings["world.comm.model"] == "full"
    assert settings["world.noise.turn"] == 0.05  # the rest of the preset as it is
    config = realism_config("high", {key: 0.0})
    assert config.world.noise.forward == 0.0 and config.world.noise.turn == 0.1


@pytest.mark.parametrize("name", ["extreme", "", "Medium", None, 3])
def test_an_unknown_preset_is_refused_naming_the_valid_ones(name: object) -> None:
    with pytest.raises(ConfigError, match=r"realism must be one of 'none', 'low', 'medium', 'high', got "):
        realism_config(name)
    with pytest.raises(ConfigError, match="realism must be one of"):
        areasearch.parallel_env(map="procedural:small", realism=name)


def _episode_hash(env: areasearch.AreaSearchParallelEnv, steps: int) -> str:
    """SHA-256 of every observation, reward and pose of ``steps`` seeded random steps."""
    digest = hashlib.sha256()
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(3)
    for _ in range(steps):
        obs, rewards, *_ = env.step({a: int(rng.integers(4)) for a in env.agents})
        for agent in sorted(obs):
            for key in sorted(obs[agent]):
                digest.update(np.ascontiguousarray(obs[agent][key]).tobytes())
        digest.update(repr(sorted(rewards.items())).encode())
        digest.update(env.world.poses.tobytes())
    return digest.hexdigest()


def test_parallel_env_none_is_bit_identical_to_the_default(small_map: str) -> None:
    plain = areasearch.parallel_env(map=small_map, num_robots=2, seed=3, max_steps=60)
    none = areasearch.parallel_env(map=small_map, num_robots=2, seed=3, max_steps=60, realism="none")
    assert none.config == plain.config
    assert _episode_hash(none, 60) == _episode_hash(plain, 60)
    noisy = areasearch.parallel_env(map=small_map, num_robots=2, seed=3, max_steps=60, realism="low")
    assert _episode_hash(noisy, 60) != _episode_hash(plain, 60)


def test_parallel_env_takes_realism_and_its_keywords_win(small_map: str) -> None:
    env = areasearch.parallel_env(map=small_map, realism="medium", noise__forward=0.2, **{"comm.model": "disc"})
    assert env.config.noise.forward == 0.2 and env.config.noise.turn == 0.05
    assert env.config.comm.model == "disc" and env.config.detection.model == "linear"
    whole = areasearch.parallel_env(map=small_map, realism="high", noise=NoiseConfig(forward=0.3))
    assert whole.config.noise == NoiseConfig(forward=0.3)  # a whole group given wins over all its preset values
    assert whole.config.detection.p_far == 0.3
    aec = areasearch.env(map=small_map, realism="low")
    assert _world_summary(aec.unwrapped.config) == EXPECTED["low"]
    over = areasearch.parallel_env(map=small_map, config=WorldConfig(num_robots=2, max_steps=77), realism="low")
    assert over.config.max_steps == 77 and _world_summary(over.config) == EXPECTED["low"]  # over ``config``


def test_gymnasium_make_takes_realism(small_map: str) -> None:
    env = gymnasium.make(areasearch.GOAL_ENV_ID, map=small_map, realism="medium", **{"detection.p_far": 0.5})
    world = env.unwrapped.config.world
    assert world.noise == EXPECTED["medium"]["noise"] and world.detection.p_far == 0.5
    assert world.comm.model == "signal"
    env.close()
    plain = gymnasium.make(areasearch.GOAL_ENV_ID, map=small_map, realism="none")
    assert plain.unwrapped.config == AreaSearchEnv(map=small_map).config
    with pytest.raises(ConfigError, match="realism must be one of"):
        gymnasium.make(areasearch.GOAL_ENV_ID, map=small_map, realism="max")


@pytest.mark.parametrize("name", REALISM_NAMES)
def test_a_short_episode_runs_under_each_preset(name: str, small_map: str) -> None:
    env = make_env(small_map, 3, 5, 100, realism_config(name))
    trace = play_episode(env, make_planner("greedy"), 5)
    metrics = env.world.metrics.as_dict()
    assert metrics["steps"] == 100 and len(trace.steps) == 4  # decisions at steps 0, 40, 80 and the end
    assert 0 < metrics["explored_pct"] <= 100 and metrics["covered_pct"] <= metrics["discovered"]
    assert env.config.world.imperfect == (name != "none")
