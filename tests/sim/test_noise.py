"""The world's imperfections: noise off reproduces the noise-free world byte for byte; each noise and the
detection probability behave at their configured rates; bad settings are named."""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pytest

from areasearch.config import DetectionConfig, NoiseConfig, WorldConfig, override
from areasearch.errors import ConfigError
from areasearch.sim.actions import bounce_walk
from areasearch.sim.noise import Imperfections
from areasearch.sim.scene import load_scene, scene_from_grid
from areasearch.sim.world import Action, World

Z99 = 2.576
"""The normal quantile of a two-sided 99 % confidence interval."""

DEFAULT_HASHES = {
    0: "fc6675eb2902f1a5babe3bda81ac60881594d69e1f96e360ad09bea64a3d7e59",
    1: "e09291a85bd92fca051afa54e74feb75c46090386f24bef7123d94b74d90ac24",
    2: "69bd8048c60bf7b37371a935870a96f7503f2be11df9e086d7900a00b1c5372a",
}
"""Hashes of :func:`episode_hash` of seeded episodes of the default, noise-free world (its fused path
alone): the noise-free world must not change by a bit."""

ALL_NOISE = {
    "noise.forward": 0.025,
    "noise.turn": 0.025,
    "noise.odometry_forward": 0.05,
    "noise.odometry_turn": 0.05,
    "noise.depth": 0.02,
    "noise.dropout": 0.1,
    "detection.model": "linear",
    "detection.p_near": 0.9,
    "detection.p_far": 0.3,
}


def play(
    config: WorldConfig, seed: int, steps: int = 300, actions_seed: int | None = None
) -> tuple[World, list[float]]:
    """A seeded episode on a small map driven by ``bounce_walk`` (its draws from the world's generator,
    or from a generator of its own with ``actions_seed``); returns the world and the step rewards."""
    world = World(config)
    rng = np.random.default_rng(seed)
    world.reset(load_scene("bormann_lab_c_rooms1"), rng)
    act_rng = rng if actions_seed is None else np.random.default_rng(actions_seed)
    turning = np.zeros(config.num_robots, dtype=np.int64)
    collided = np.zeros(config.num_robots, dtype=bool)
    rewards = []
    for _ in range(steps):
        result = world.step(bounce_walk(collided, turning, act_rng))
        collided = result.collided
        rewards.append(result.reward)
    return world, rewards


def episode_hash(world: World, rewards: list[float]) -> str:
    """SHA-256 of an episode's rewards, poses, trajectory, map, depth images, target times and metrics."""
    h = hashlib.sha256()
    for reward in rewards:
        h.update(np.float64(reward).tobytes())
    mapper = world.mapper
    assert mapper is not None
    for a in (
        world.poses,
        world.trajectory,
        mapper.explored,
        mapper.occupied,
        mapper.targets,
        mapper.occupied_at,
        world.depth,
        world.discovered_at,
        world.covered_at,
    ):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(json.dumps(world.metrics.as_dict(), sort_keys=True).encode())
    return h.hexdigest()


@pytest.mark.parametrize("seed", sorted(DEFAULT_HASHES))
def test_default_world_is_bit_identical_to_the_noise_free_world(seed: int) -> None:
    world, rewards = play(WorldConfig(), seed)
    assert episode_hash(world, rewards) == DEFAULT_HASHES[seed]
    assert world.believed_poses is world.poses and world.noise is None


def test_noise_set_to_zero_is_the_default() -> None:
    explicit = WorldConfig(noise=NoiseConfig(0.0, 0.0, 0.0, 0.0, 0.0, 0.0), detection=DetectionConfig("certain"))
    assert not explicit.imperfect
    assert episode_hash(*play(explicit, 0)) == DEFAULT_HASHES[0]


def test_noisy_path_without_noise_reproduces_the_fused_path() -> None:
    """Detection ``constant`` with p = 1 takes the noisy path (render, map, detect, cover step by step)
    with nothing random in it: the same map, targets and metrics as the fused kernel's."""
    fused, fused_rewards = play(WorldConfig(), 3, actions_seed=7)
    noisy, noisy_rewards = play(override(WorldConfig(), **{"detection.model": "constant"}), 3, actions_seed=7)
    assert noisy_rewards == fused_rewards
    assert noisy.noise is not None and fused.noise is None
    for name in ("poses", "trajectory", "depth", "discovered_at", "covered_at"):
        np.testing.assert_array_equal(getattr(noisy, name), getattr(fused, name), err_msg=name)
    assert noisy.mapper is not None and fused.mapper is not None
    for name in ("explored", "occupied", "targets", "occupied_at"):
        np.testing.assert_array_equal(getattr(noisy.mapper, name), getattr(fused.mapper, name), err_msg=name)
    assert noisy.metrics.as_dict() == fused.metrics.as_dict()
    np.testing.assert_array_equal(noisy.believed_poses, noisy.poses)


def test_same_seed_same_noisy_episode() -> None:
    config = override(WorldConfig(), **ALL_NOISE)
    (a, rewards_a), (b, rewards_b) = play(config, 5, steps=150), play(config, 5, steps=150)
    assert episode_hash(a, rewards_a) == episode_hash(b, rewards_b)
    np.testing.assert_array_equal(a.believed_poses, b.believed_poses)
    assert episode_hash(*play(config, 6, steps=150)) != episode_hash(a, rewards_a)


def open_scene(width_m: float = 40.0, height_m: float = 10.0):  # type: ignore[no-untyped-def]
    cell = 0.05
    free = np.zeros((int(height_m / cell), int(width_m / cell)), dtype=bool)
    free[2:-2, 2:-2] = True
    return scene_from_grid("open", free, cell)


def imperfections(**noise: float) -> Imperfections:
    config = override(WorldConfig(num_robots=1), **{f"noise.{k}": v for k, v in noise.items()})
    return Imperfections(config, open_scene(), np.random.default_rng(11))


def test_action_noise_is_uniform_within_its_fraction() -> None:
    nz = imperfections(forward=0.025, turn=0.05)
    forward, turn = nz.commands(2000, 0.25, math.radians(10))
    e_f, e_t = forward / 0.25 - 1, turn / math.radians(10) - 1
    for e, f in ((e_f, 0.025), (e_t, 0.05)):
        assert np.abs(e).max() <= f + 1e-12
        assert abs(e.mean()) < Z99 * (f / math.sqrt(3)) / math.sqrt(len(e))
        assert e.std() == pytest.approx(f / math.sqrt(3), rel=0.06)  # 99 % CI of a uniform's sd, n = 2000
        assert abs(np.mean(np.abs(e) > f / 2) - 0.5) < Z99 * 0.5 / math.sqrt(len(e))


def test_a_noisy_forward_moves_within_its_fraction_and_odometry_follows_exactly() -> None:
    world = World(override(WorldConfig(num_robots=1), **{"noise.forward": 0.1, "targets.count": 5}))
    world.reset(open_scene(), np.random.default_rng(0), poses=[[2.0, 5.0, 0.0]])
    moved = []
    for _ in range(20):
        x = world.poses[0, 0]
        world.step(np.array([int(Action.FORWARD)]))
        moved.append(world.poses[0, 0] - x)
    assert 0.225 - 1e-12 <= min(moved) < max(moved) <= 0.275 + 1e-12
    assert world.metrics.path_length_m[0] == pytest.approx(sum(moved))
    np.testing.assert_array_equal(world.believed_poses, world.poses)  # perfect odometry: no drift


def test_odometry_drift_grows_as_a_random_walk_on_a_straight_drive() -> None:
    """After n FORWARDs of d metres with a relative odometry error of deviation sigma the believed pose
    is off by a normal of deviation d sigma sqrt(n) along the way: mean |error| d sigma sqrt(2 n / pi)."""
    sigma, d, n, robots = 0.05, 0.25, 100, 2000
    nz = imperfections(odometry_forward=sigma)
    true = np.tile([1.0, 5.0, 0.0], (robots, 1))
    believed = true.copy()
    for _ in range(n):
        before = true.copy()
        true[:, 0] += d
        nz.odometry(before, true, believed)
    error = believed[:, 0] - true[:, 0]
    np.testing.assert_allclose(believed[:, 1:], true[:, 1:])  # no heading error without turn noise
    expected = d * sigma * math.sqrt(2 * n / math.pi)
    spread = d * sigma * math.sqrt(n) * math.sqrt(1 - 2 / math.pi)
    assert abs(np.abs(error).mean() - expected) < Z99 * spread / math.sqrt(robots)
    assert abs(error.mean()) < Z99 * d * sigma * math.sqrt(n) / math.sqrt(robots)


def test_odometry_drift_in_the_world_matches_the_model() -> None:
    """The same law through :meth:`World.step`: eight robots drive straight down lanes of an open room,
    25 episodes, 40 FORWARDs each."""
    sigma, d, n = 0.05, 0.25, 40
    config = override(WorldConfig(num_robots=8), **{"noise.odometry_forward": sigma, "targets.count": 5})
    world, errors = World(config), []
    lanes = [[1.0, 1.0 + i, 0.0] for i in range(8)]
    for seed in range(25):
        world.reset(open_scene(), np.random.default_rng(seed), poses=lanes)
        for _ in range(n):
            world.step(np.full(8, int(Action.FORWARD)))
        assert world.metrics.collisions.sum() == 0
        errors.append(world.believed_poses[:, 0] - world.poses[:, 0])
    error = np.abs(np.concatenate(errors))
    expected = d * sigma * math.sqrt(2 * n / math.pi)
    spread = d * sigma * math.sqrt(n) * math.sqrt(1 - 2 / math.pi)
    assert abs(error.mean() - expected) < Z99 * spread / math.sqrt(len(error))


def test_odometry_turn_error_turns_the_believed_heading() -> None:
    sigma, n, robots = 0.05, 36, 2000
    nz = imperfections(odometry_turn=sigma)
    turn = math.radians(10)
    true = np.tile([10.0, 5.0, 0.0], (robots, 1))
    believed = true.copy()
    for _ in range(n):
        before = true.copy()
        true[:, 2] = (true[:, 2] + turn + math.pi) % (2 * math.pi) - math.pi
        nz.odometry(before, true, believed)
    error = (believed[:, 2] - true[:, 2] + math.pi) % (2 * math.pi) - math.pi
    assert error.std() == pytest.approx(turn * sigma * math.sqrt(n), rel=0.06)


def test_believed_pose_drifts_in_the_world_and_the_map_is_fused_there() -> None:
    config = override(WorldConfig(num_robots=1), **{"noise.odometry_forward": 0.2, "targets.count": 5})
    world = World(config)
    world.reset(open_scene(), np.random.default_rng(1), poses=[[2.0, 5.0, 0.0]])
    for _ in range(60):
        world.step(np.array([int(Action.FORWARD)]))
    assert world.poses[0, 0] == pytest.approx(2.0 + 60 * 0.25)
    assert abs(world.believed_poses[0, 0] - world.poses[0, 0]) > 0.01
    np.testing.assert_array_equal(world.believed_trajectory[60], world.believed_poses)
    np.testing.assert_array_equal(world.trajectory[60], world.poses)


def test_depth_noise_and_dropout_match_their_settings() -> None:
    nz = imperfections(depth=0.03, dropout=0.2)
    nz.clean[:] = 2.0
    out = np.empty_like(nz.clean)
    kept, relative = [], []
    for _ in range(5):
        nz.perturb(out)
        kept.append(out > 0)
        relative.append(out[out > 0] / 2.0 - 1)
    dropped = 1 - np.concatenate([k.ravel() for k in kept]).mean()
    pixels = 5 * nz.clean.size
    assert abs(dropped - 0.2) < Z99 * math.sqrt(0.2 * 0.8 / pixels)
    assert np.concatenate(relative).std() == pytest.approx(0.03, rel=0.03)


@pytest.mark.parametrize(
    ("model", "p_near", "p_far", "distance", "p"),
    [("constant", 0.3, 1.0, 2.0, 0.3), ("linear", 0.9, 0.1, 1.6, 0.5), ("linear", 0.8, 0.2, 3.2, 0.2)],
)
def test_detection_rate_matches_its_probability(
    model: str, p_near: float, p_far: float, distance: float, p: float
) -> None:
    config = override(
        WorldConfig(num_robots=1), **{"detection.model": model, "detection.p_near": p_near, "detection.p_far": p_far}
    )
    nz = Imperfections(config, open_scene(), np.random.default_rng(2))
    draws = 2000
    targets_xy = np.tile([5.0 + distance, 5.0], (draws, 1))
    detected = nz.detect(np.arange(draws), np.array([5.0, 5.0, 0.0]), targets_xy)
    assert abs(len(detected) / draws - p) < Z99 * math.sqrt(p * (1 - p) / draws) + 1e-12


def test_undetected_targets_are_not_discovered_until_covered() -> None:
    """Detection probability 0: no target is ever discovered by sight; one a robot covers is (the rule:
    covering a target also detects it)."""
    config = override(WorldConfig(), **{"detection.model": "constant", "detection.p_near": 0.0})
    world, _ = play(config, 0, steps=400)
    m = world.metrics
    assert m.explored_fraction > 0.5
    assert m.discovered == m.covered
    assert (world.discovered_at[world.covered] == world.covered_at[world.covered]).all()
    assert world.mapper is not None and not world.mapper.targets.any()


def test_all_noise_plays_and_keeps_the_books() -> None:
    world, _ = play(override(WorldConfig(), **ALL_NOISE), 0, steps=400)
    m, mapper = world.metrics, world.mapper
    assert mapper is not None
    assert 0 < m.explored_fraction <= 1 and m.covered <= m.discovered <= len(world.covered)
    assert m.discovered == int(world.discovered.sum()) and m.covered == int(world.covered.sum())
    pending = world.discovered & ~world.covered
    assert mapper.targets.sum() <= pending.sum() and (pending.sum() == 0) == (not mapper.targets.any())
    assert not np.array_equal(world.believed_poses, world.poses)
    assert mapper.targets[world.target_map_cells[pending, 0], world.target_map_cells[pending, 1]].all()
    seen = world.discovered
    assert (world.target_map_cells[seen] != world.target_cells[seen]).any()  # marked where believed
    np.testing.assert_array_equal(world.target_map_cells[~seen], world.target_cells[~seen])


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("noise.forward", -0.1),
        ("noise.turn", 2.0),
        ("noise.odometry_forward", float("nan")),
        ("noise.odometry_turn", -1e-9),
        ("noise.depth", "high"),
        ("noise.dropout", 1.5),
        ("detection.model", "sometimes"),
        ("detection.p_near", -0.1),
        ("detection.p_far", 1.01),
    ],
)
def test_bad_settings_name_their_field(key: str, value: object) -> None:
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        World(override(WorldConfig(), **{key: value}))
