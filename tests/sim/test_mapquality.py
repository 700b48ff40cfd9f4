"""The map-quality figure (:mod:`areasearch.sim.mapquality`): 0 without noise (the truth is the map a
perfect mapper makes), growing with odometry noise, its four parts adding up to the wrong cells."""

from __future__ import annotations

import numpy as np
import pytest

from areasearch.config import WorldConfig, override
from areasearch.sim.actions import bounce_walk
from areasearch.sim.mapquality import PARTS, map_quality, scene_truth, score, true_map
from areasearch.sim.scene import load_scene
from areasearch.sim.world import World

UNKNOWN, FREE, OCCUPIED = 0, 1, 2


def play(settings: dict[str, object], seed: int = 3, steps: int = 150) -> World:
    """A seeded episode of 3 robots on a small map driven by ``bounce_walk`` (its own generator, so that
    every setting meets the same actions)."""
    world = World(override(WorldConfig(num_robots=3), **settings))
    world.reset(load_scene("bormann_lab_c_rooms1"), np.random.default_rng(seed))
    act_rng = np.random.default_rng(seed + 100)
    turning = np.zeros(3, dtype=np.int64)
    collided = np.zeros(3, dtype=bool)
    for _ in range(steps):
        collided = world.step(bounce_walk(collided, turning, act_rng)).collided
    return world


def states(explored: np.ndarray, occupied: np.ndarray) -> np.ndarray:
    """(H, W) each cell's state: unknown, free or occupied."""
    return np.where(occupied, OCCUPIED, np.where(explored, FREE, UNKNOWN))


def test_score_counts_each_kind_of_wrong_cell() -> None:
    # truth:   row 0 free, free, occupied, unseen, unseen, free, occupied
    true_explored = np.array([[1, 1, 1, 0, 0, 1, 1]], dtype=bool)
    true_occupied = np.array([[0, 0, 1, 0, 0, 0, 1]], dtype=bool)
    # map:     free (right), occupied (phantom), free (missed), free (misplaced), unknown (not judged),
    #          unknown (unmapped), occupied (right)
    explored = np.array([[1, 1, 1, 1, 0, 0, 1]], dtype=bool)
    occupied = np.array([[0, 1, 0, 0, 0, 0, 1]], dtype=bool)
    q = score(explored, occupied, true_explored, true_occupied)
    assert (q.judged, q.phantom, q.missed, q.misplaced, q.unmapped) == (6, 1, 1, 1, 1)
    assert q.wrong == 4 and q.error_pct == pytest.approx(100 * 4 / 6)
    assert sum(q.parts_pct().values()) == pytest.approx(q.error_pct)
    empty = np.zeros((2, 2), dtype=bool)
    assert score(empty, empty, empty, empty).error_pct == 0.0


def test_noise_free_maps_score_zero_and_match_the_scene() -> None:
    world = play({})
    assert world.noise is None
    q = map_quality(world)
    assert q.judged > 1000 and q.wrong == 0 and q.error_pct == 0.0
    # the perfect map's obstacles are exactly the seen cells that are not free floor (no discretisation gap)
    assert world.mapper is not None
    explored, occupied = scene_truth(world)
    np.testing.assert_array_equal(occupied, world.mapper.occupied)
    assert score(world.mapper.explored, world.mapper.occupied, explored, occupied).wrong == 0


def test_the_noisy_path_tracks_the_perfect_map() -> None:
    """Imperfect but with the poses and the depth exact (detection only): the team map is the perfect one,
    and so is what the noisy path keeps as the truth."""
    world = play({"detection.model": "constant", "detection.p_near": 0.5, "detection.p_far": 0.5})
    assert world.noise is not None and world.mapper is not None
    explored, occupied = true_map(world)
    np.testing.assert_array_equal(explored, world.mapper.explored)
    np.testing.assert_array_equal(occupied, world.mapper.occupied)
    assert map_quality(world).wrong == 0
    # the same moves in the noise-free world map the same cells
    noise_free = play({})
    assert noise_free.mapper is not None
    np.testing.assert_array_equal(noise_free.mapper.explored, explored)
    np.testing.assert_array_equal(noise_free.mapper.occupied, occupied)


def test_error_grows_with_odometry_noise_and_its_parts_add_up() -> None:
    errors = []
    worlds = [play({"noise.odometry_forward": s, "noise.odometry_turn": s}) for s in (0.0, 0.01, 0.05)]
    for world in worlds:
        q = map_quality(world)
        errors.append(q.error_pct)
        assert q.wrong == sum(getattr(q, name) for name in PARTS)
        assert sum(q.parts_pct().values()) == pytest.approx(q.error_pct)
    assert errors[0] == 0.0 < errors[1] < errors[2]
    # the parts against a cell-by-cell comparison of the states
    world_noisy = worlds[-1]
    assert world_noisy.noise is not None and world_noisy.mapper is not None
    mapped = states(world_noisy.mapper.explored, world_noisy.mapper.occupied)
    truth = states(*true_map(world_noisy))
    judged = (mapped != UNKNOWN) | (truth != UNKNOWN)
    q = map_quality(world_noisy)
    assert q.judged == int(judged.sum())
    assert q.wrong == int((judged & (mapped != truth)).sum())
    assert q.phantom == int(((mapped == OCCUPIED) & (truth == FREE)).sum())
    assert q.unmapped == int(((mapped == UNKNOWN) & (truth == FREE)).sum())


def test_a_robot_map_under_limited_communication_is_scored_too() -> None:
    world = play({"comm.model": "disc", "comm.range_m": 1.0, "noise.odometry_forward": 0.02})
    assert world.knowledge is not None
    team = map_quality(world)
    for robot_map in world.robot_maps:
        own = map_quality(world, robot_map)
        assert own.judged <= team.judged + own.misplaced and 0.0 <= own.error_pct <= 100.0
