"""Log-odds occupancy (``mapping.occupancy``, areasearch.sim.occupancy): the kernel agrees with its plain
reference; the sticky default is the noise-free world bit for bit; with perfect depth log-odds builds the
sticky map; under depth noise it clears the phantom obstacles sticky keeps, and the team explores as it does
without noise; merges, records and bad settings."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage
from test_noise import DEFAULT_HASHES, episode_hash, play

from areasearch.config import MappingConfig, WorldConfig, override, search_config
from areasearch.errors import ConfigError
from areasearch.sim.depth import camera_tables
from areasearch.sim.mapper import Mapper
from areasearch.sim.occupancy import integrate_log_odds_reference, merge_log_odds
from areasearch.sim.scene import load_scene

LOG_ODDS = {"mapping.occupancy": "log_odds"}
DEPTH_NOISE = {"noise.depth": 0.02}


def _log_odds_world(seed: int, steps: int, **settings: object):  # type: ignore[no-untyped-def]
    return play(override(WorldConfig(), **settings), seed, steps=steps, actions_seed=7)[0]


def test_the_kernel_agrees_with_its_reference_on_random_noisy_depth() -> None:
    """Rendered frames with depth noise and dropout, and frames of random depth (points everywhere, off the
    grid, non-finite, none), fused one after another: the same log-odds, maps, stamps and new cells."""
    world = _log_odds_world(0, 40, **DEPTH_NOISE, **{"noise.dropout": 0.05}, **LOG_ODDS)
    scene, camera = world.scene, world.config.camera
    tables = camera_tables(camera)
    mapping = MappingConfig(occupancy="log_odds")
    mapper = Mapper(scene.shape, scene.cell_m, scene.origin_xy, obstacle_top_m=0.6, occupancy=mapping)
    ref = {
        "log_odds": np.zeros(scene.shape, np.float32),
        "explored": np.zeros(scene.shape, bool),
        "occupied": np.zeros(scene.shape, bool),
        "occupied_at": np.zeros(scene.shape, np.int32),
    }
    rng = np.random.default_rng(3)
    noisy = (world.noise.clean * (1 + 0.02 * rng.standard_normal(world.depth.shape))).astype(np.float32)
    frames = [(noisy, world.poses)]
    for _ in range(12):
        depth = rng.uniform(0.0, 6.0, world.depth.shape).astype(np.float32)
        depth[rng.random(depth.shape) < 0.1] = 0.0
        depth[rng.random(depth.shape) < 0.02] = np.nan
        depth[rng.random(depth.shape) < 0.02] = np.inf
        frames.append((depth, world.poses + rng.normal(0, [0.05, 0.05, 0.2], world.poses.shape)))
    frames += [frames[0]] * 5  # the same view again: votes accumulate and clamp
    for depth, poses in frames:
        new = np.sort(mapper.integrate(depth, camera, poses))
        expected = integrate_log_odds_reference(
            depth, poses, tables.xu, tables.slope, camera.mount_height_m, mapper.floor_tolerance_m, 0.6,
            scene.cell_m, scene.origin_xy, mapping.log_odds(), ref["log_odds"], ref["explored"], ref["occupied"],
            ref["occupied_at"], mapper.integrations,
        )  # fmt: skip
        np.testing.assert_array_equal(new, expected)
        for name, array in ref.items():
            np.testing.assert_array_equal(getattr(mapper, name), array, err_msg=name)
    assert mapper.log_odds is not None and mapper.log_odds.max() > 0 and mapper.log_odds.min() < 0
    assert np.isclose(mapper.log_odds.max(), mapping.log_odds()[3]) and np.isclose(mapper.log_odds.min(), -1.99, 0.01)
    mapper.reset()
    assert not mapper.log_odds.any() and not mapper.occupied.any() and mapper.integrations == 0


def test_the_sticky_default_is_the_noise_free_world_bit_for_bit() -> None:
    config = WorldConfig(mapping=MappingConfig(occupancy="sticky"))
    assert config == WorldConfig() and not config.imperfect
    world, rewards = play(config, 0)
    assert episode_hash(world, rewards) == DEFAULT_HASHES[0]
    assert world.mapper is not None and world.mapper.log_odds is None


def test_log_odds_runs_on_the_noisy_path_and_builds_the_sticky_map_from_perfect_depth() -> None:
    """Without noise, every cell log-odds occupies is one sticky occupies and no frame votes a wall free:
    the same occupied set, explored set and stamps, step for step the same moves."""
    assert search_config(LOG_ODDS).world.imperfect
    sticky = _log_odds_world(3, 300, **{"detection.model": "constant"})
    log_odds = _log_odds_world(3, 300, **LOG_ODDS)
    assert log_odds.noise is not None and log_odds.mapper is not None and sticky.mapper is not None
    np.testing.assert_array_equal(log_odds.trajectory, sticky.trajectory)
    for name in ("occupied", "explored", "occupied_at"):
        np.testing.assert_array_equal(getattr(log_odds.mapper, name), getattr(sticky.mapper, name), err_msg=name)
    assert log_odds.mapper.occupied.sum() > 300


def phantoms(world, margin_cells: int = 0) -> int:  # type: ignore[no-untyped-def]
    """Occupied cells of the world's map that are free in the scene, more than ``margin_cells`` from a wall."""
    away = ndimage.distance_transform_edt(world.scene.free) > margin_cells
    return int((world.mapper.occupied & world.scene.free & away).sum())


def test_log_odds_clears_the_phantom_obstacles_of_depth_noise() -> None:
    """noise.depth 0.02, 300 steps on a small map: sticky keeps ~1,250 phantom cells (the points of wall faces
    that fell short, up to four cells before the walls); log-odds keeps a handful, all next to a wall, and
    keeps the walls it saw."""
    sticky = _log_odds_world(0, 300, **DEPTH_NOISE)
    log_odds = _log_odds_world(0, 300, **DEPTH_NOISE, **LOG_ODDS)
    assert phantoms(sticky) > 800 and phantoms(sticky, 2) > 200
    assert phantoms(log_odds) < 20 and phantoms(log_odds, 1) == 0
    walls = ~sticky.scene.free
    assert (log_odds.mapper.occupied & walls).sum() > 0.95 * (sticky.mapper.occupied & walls).sum()


def test_a_greedy_team_under_depth_noise_explores_with_log_odds_as_without_noise() -> None:
    from areasearch.harness.episodes import make_env, play_episode
    from areasearch.planners import make_planner

    def explored(settings: dict[str, object]) -> float:
        env = make_env("robotathome_sarmis", 3, 0, 800, search_config(settings))
        return float(play_episode(env, make_planner("greedy"), 0).info["explored_pct"])

    clean, sticky, log_odds = explored({}), explored(DEPTH_NOISE), explored({**DEPTH_NOISE, **LOG_ODDS})
    assert log_odds >= clean - 5.0  # measured: 80.6 % without noise, 82.2 % with log-odds
    assert sticky < clean - 15.0  # 54.2 %: phantom walls close the doorways


def test_same_seed_same_log_odds_episode() -> None:
    settings = {**DEPTH_NOISE, **LOG_ODDS, "noise.odometry_forward": 0.05, "noise.dropout": 0.1}
    config = override(WorldConfig(), **settings)
    (a, rewards_a), (b, rewards_b) = play(config, 5, steps=150), play(config, 5, steps=150)
    assert episode_hash(a, rewards_a) == episode_hash(b, rewards_b)
    np.testing.assert_array_equal(a.mapper.log_odds, b.mapper.log_odds)
    assert episode_hash(*play(config, 6, steps=150)) != episode_hash(a, rewards_a)


def test_a_merged_group_shares_the_mean_log_odds() -> None:
    """Under limited communication each robot keeps its own log-odds map; a group's members end every step
    with the members' mean and occupied where it is positive."""
    world = _log_odds_world(1, 120, **DEPTH_NOISE, **LOG_ODDS, **{"comm.model": "disc", "comm.range_m": 3.0})
    assert world.knowledge is not None
    for group in world.comm_groups:
        first = world.robot_maps[int(group[0])]
        assert first.log_odds is not None
        np.testing.assert_array_equal(first.occupied, first.log_odds > 0)
        for r in group[1:]:
            np.testing.assert_array_equal(world.robot_maps[int(r)].log_odds, first.log_odds)
    a = np.array([[1.0, -2.0, 0.5]], np.float32)
    b = np.array([[-1.0, 0.0, 0.1]], np.float32)
    np.testing.assert_array_equal(merge_log_odds([a, b]), np.array([[0.0, -1.0, 0.3]], np.float32))


def test_a_merge_stamps_cells_it_turns_occupied() -> None:
    from areasearch.sim.knowledge import TeamKnowledge

    config = override(WorldConfig(num_robots=2), **LOG_ODDS, **{"comm.model": "disc", "comm.range_m": 50.0})
    scene = load_scene("bormann_lab_c_rooms1")
    known = TeamKnowledge(config, scene, 0, np.random.default_rng(0))
    a, b = known.maps
    assert a.log_odds is not None and b.log_odds is not None
    a.log_odds[5, 5], a.occupied[5, 5] = 3.0, True  # a saw an obstacle; b saw it free once
    b.log_odds[5, 5] = -0.4
    a.log_odds[6, 6], b.log_odds[6, 6] = -2.0, 0.8  # a phantom of b's, cleared by a's evidence
    b.occupied[6, 6] = True
    a.integrations, b.integrations = 4, 9
    known.share(1, np.array([[2.0, 2.0], [2.5, 2.0]]), np.array([[2.0, 2.0], [2.5, 2.0]]), np.zeros((0, 2), int))
    assert [g.tolist() for g in known.groups] == [[0, 1]]
    for m in (a, b):
        assert m.occupied[5, 5] and not m.occupied[6, 6]
    assert b.occupied_at[5, 5] == 9 and a.occupied_at[5, 5] == 0


def test_a_record_holds_the_mapping_group_only_when_it_is_set(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from areasearch.harness.evaluate import EvalPlan, run_config

    plan = EvalPlan(["greedy"], [2], ["bormann_office_d_rooms2"], 1, 0, 40, tmp_path / "run")
    assert "mapping" not in run_config(plan)["config"]["world"]
    world = run_config(plan.with_settings(LOG_ODDS))["config"]["world"]
    assert world["mapping"] == {"occupancy": "log_odds", "p_hit": 0.7, "p_miss": 0.4, "p_min": 0.12, "p_max": 0.97}


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("mapping.occupancy", "octree", r"mapping\.occupancy must be one of 'sticky', 'log_odds'"),
        ("mapping.p_hit", 0.4, r"mapping\.p_hit must be above 0\.5"),
        ("mapping.p_hit", 1.0, r"mapping\.p_hit must be a probability in \(0, 1\)"),
        ("mapping.p_miss", 0.6, r"mapping\.p_miss must be below 0\.5"),
        ("mapping.p_miss", 0.0, r"mapping\.p_miss must be a probability"),
        ("mapping.p_min", 0.5, r"mapping\.p_min must be below 0\.5"),
        ("mapping.p_max", 0.3, r"mapping\.p_max must be above 0\.5"),
        ("mapping.p_max", "high", r"mapping\.p_max must be a finite number"),
        ("mapping.p_hit", True, r"mapping\.p_hit must be a finite number"),
    ],
)
def test_bad_mapping_settings_name_their_field(key: str, value: object, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        search_config({key: value})
