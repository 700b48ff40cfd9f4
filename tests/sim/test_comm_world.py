"""Limited communication in the world (areasearch.sim.knowledge through World): ``full`` is today's world
byte for byte; out of touch, a robot keeps its own map and targets and merges them on contact; the metrics
count the truth whatever the robots know."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_noise import DEFAULT_HASHES, episode_hash, open_scene, play

from areasearch.config import CommConfig, WorldConfig, override, search_config
from areasearch.errors import ConfigError
from areasearch.sim.world import Action, World

DISC = {"comm.model": "disc", "comm.range_m": 2.0}


def test_full_communication_is_the_default_world_bit_for_bit() -> None:
    config = WorldConfig(comm=CommConfig(model="full"))
    assert config == WorldConfig() and not config.imperfect
    world, rewards = play(config, 0)
    assert episode_hash(world, rewards) == DEFAULT_HASHES[0]
    assert world.knowledge is None and world.heard is None
    assert all(m is world.mapper for m in world.robot_maps)
    assert [g.tolist() for g in world.comm_groups] == [[0, 1, 2]]


def test_comm_settings_reach_the_world() -> None:
    config = search_config({"comm.model": "disc", "comm.range_m": 5})
    assert config.world.comm == CommConfig(model="disc", range_m=5.0)
    assert config.world.imperfect
    with pytest.raises(ConfigError, match=r"comm\.model must be one of"):
        search_config({"comm.model": "radio"})


def test_the_metrics_count_the_truth_under_limited_communication() -> None:
    """Without noise, what the team truly sees and covers does not depend on who tells whom: the same moves
    give the same metrics and the same union map as full communication (on the noisy path without noise)."""
    full, full_rewards = play(override(WorldConfig(), **{"detection.model": "constant"}), 3, actions_seed=7)
    apart, apart_rewards = play(override(WorldConfig(), **DISC), 3, actions_seed=7)
    assert apart_rewards == full_rewards
    assert apart.metrics.as_dict() == full.metrics.as_dict()
    np.testing.assert_array_equal(apart.poses, full.poses)
    assert apart.mapper is not None and full.mapper is not None
    for name in ("explored", "occupied", "targets"):
        np.testing.assert_array_equal(getattr(apart.mapper, name), getattr(full.mapper, name), err_msg=name)
    maps = apart.robot_maps
    np.testing.assert_array_equal(np.logical_or.reduce([m.explored for m in maps]), apart.mapper.explored)
    np.testing.assert_array_equal(np.logical_or.reduce([m.occupied for m in maps]), apart.mapper.occupied)
    assert apart.knowledge is not None
    np.testing.assert_array_equal(apart.knowledge.found.any(axis=0), apart.discovered)


def _walk(world: World, actions: list[int], steps: int) -> None:
    for _ in range(steps):
        world.step(np.array(actions, dtype=np.int64))


def test_a_robot_out_of_touch_keeps_its_own_map_and_merges_it_on_contact() -> None:
    world = World(override(WorldConfig(num_robots=2), **{"comm.model": "disc", "comm.range_m": 1.0}))
    world.reset(open_scene(), np.random.default_rng(0), poses=[[3.0, 5.0, 0.0], [15.0, 5.0, math.pi]])
    assert [g.tolist() for g in world.comm_groups] == [[0], [1]]
    a, b = world.robot_maps
    assert a is not b and not (a.explored & b.explored).any()
    assert world.heard is not None and world.heard.steps[0, 1] == -1
    only_b = b.explored.copy()
    forward = int(Action.FORWARD)
    _walk(world, [forward, forward], 10)  # 12 m apart, closing 0.5 m a step: 7 m apart
    assert [g.tolist() for g in world.comm_groups] == [[0], [1]]
    assert not (a.explored & only_b).any()
    _walk(world, [forward, forward], 13)  # half a metre apart
    assert float(np.hypot(*(world.poses[0, :2] - world.poses[1, :2]))) <= 1.0
    assert [g.tolist() for g in world.comm_groups] == [[0, 1]]
    np.testing.assert_array_equal(a.explored, b.explored)
    np.testing.assert_array_equal(a.occupied, b.occupied)
    assert a.explored[only_b].all()
    met = world.metrics.steps
    assert world.heard.steps[0, 1] == met and world.heard.steps[1, 0] == met
    np.testing.assert_allclose(world.heard.positions[0, 1], world.believed_poses[1, :2])
    turn = int(Action.TURN_LEFT)
    _walk(world, [turn, turn], 18)  # about turn, in touch
    _walk(world, [forward, forward], 6)  # apart: about 1 m after one step (the range), 1.5 m after two
    assert [g.tolist() for g in world.comm_groups] == [[0], [1]]
    last = int(world.heard.steps[0, 1])
    assert last in (met + 18, met + 19) and last == world.heard.steps[1, 0]
    np.testing.assert_allclose(world.heard.positions[0, 1], world.trajectory[last, 1, :2])
    np.testing.assert_allclose(world.heard.positions[1, 0], world.trajectory[last, 0, :2])


@pytest.mark.parametrize("model", ["disc", "signal"])
def test_five_robots_keep_partitioned_groups(model: str) -> None:
    world, _ = play(override(WorldConfig(num_robots=5), **{"comm.model": model, "comm.range_m": 2.0}), 4, steps=120)
    found = sorted(int(r) for group in world.comm_groups for r in group)
    assert found == list(range(5))
    assert world.knowledge is not None
    for group in world.comm_groups:
        first = world.robot_maps[int(group[0])]
        for r in group[1:]:
            np.testing.assert_array_equal(world.robot_maps[int(r)].explored, first.explored)
        assert (world.knowledge.found[group] == world.knowledge.found[group[0]]).all()
