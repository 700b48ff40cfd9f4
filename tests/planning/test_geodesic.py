"""Tests for the planning grid and the FMM distances (areasearch.planning.grid, .window, .fmm, .geodesic)."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from scipy import ndimage

from areasearch.planning.geodesic import METHODS, Method, distance_field, distance_fields, distances_to
from areasearch.planning.grid import Box, InflatedObstacles, clearance_threshold_m, planning_grid, region_box
from areasearch.planning.window import window_grid
from areasearch.sim.scene import load_scene

CELL_M = 0.05
RADIUS_M = 0.18


def _euclid(shape: tuple[int, int], source: tuple[int, int]) -> np.ndarray:
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    return np.hypot(yy - source[0], xx - source[1])


# ---------------------------------------------------------------------------------- planning grid


def test_planning_grid_without_obstacles_is_all_passable() -> None:
    explored = np.zeros((8, 9), dtype=bool)
    explored[2:5, 2:6] = True
    assert planning_grid(explored, np.zeros_like(explored), CELL_M, RADIUS_M).all()


def test_inflation_is_the_distance_transform_rule() -> None:
    occupied = np.zeros((41, 41), dtype=bool)
    occupied[20, 20] = True  # one obstacle cell: the blocked set is a disc
    occupied[5, 3:30] = True  # and a straight wall
    passable = planning_grid(np.ones_like(occupied), occupied, CELL_M, RADIUS_M)
    edt_cells = ndimage.distance_transform_edt(~occupied)
    expected = edt_cells > clearance_threshold_m(CELL_M, RADIUS_M) / CELL_M
    np.testing.assert_array_equal(passable, expected)
    # by hand: the threshold is 0.18 m + 0.05 m * sqrt(1/2) = 4.31 cells
    assert not passable[20, 24] and not passable[23, 23] and passable[20, 25] and passable[24, 22]


def test_keep_free_unblocks_a_robot_next_to_a_new_obstacle() -> None:
    occupied = np.zeros((20, 20), dtype=bool)
    occupied[10, 12] = True
    robot = np.array([[10, 10]])
    assert not planning_grid(np.ones_like(occupied), occupied, CELL_M, RADIUS_M)[10, 10]
    assert planning_grid(np.ones_like(occupied), occupied, CELL_M, RADIUS_M, keep_free=robot)[10, 10]
    with pytest.raises(ValueError, match="outside"):
        planning_grid(np.ones_like(occupied), occupied, CELL_M, RADIUS_M, keep_free=np.array([[20, 0]]))


def test_unknown_margin() -> None:
    explored = np.zeros((30, 30), dtype=bool)
    explored[10:15, 10:15] = True
    occupied = np.zeros_like(explored)
    everywhere = planning_grid(explored, occupied, CELL_M, RADIUS_M)
    near = planning_grid(explored, occupied, CELL_M, RADIUS_M, unknown_margin_m=3 * CELL_M)
    known_only = planning_grid(explored, occupied, CELL_M, RADIUS_M, unknown_margin_m=0.0)
    assert everywhere.all()
    np.testing.assert_array_equal(known_only, explored)
    expected = np.zeros_like(explored)
    expected[7:18, 7:18] = True  # 3 cells (Chebyshev) around the explored square
    np.testing.assert_array_equal(near, expected)
    anchor = np.zeros_like(explored)
    anchor[14, 14] = True  # e.g. a frontier cell: unknown space is passable only near it
    near_anchor = planning_grid(explored, occupied, CELL_M, RADIUS_M, unknown_margin_m=3 * CELL_M, margin_from=anchor)
    expected = explored.copy()
    expected[11:18, 11:18] = True
    np.testing.assert_array_equal(near_anchor, expected)


def test_diagonal_pinch_is_opened() -> None:
    # with a tiny radius only the occupied cells themselves are blocked (threshold 0.81 cell)
    occupied = np.zeros((4, 4), dtype=bool)
    occupied[1, 1] = occupied[2, 2] = True  # cells (1, 2) and (2, 1) touch only at a corner
    occupied[0, :] = occupied[3, :] = occupied[:, 0] = occupied[:, 3] = True
    passable = planning_grid(np.ones_like(occupied), occupied, 1.0, 0.1)
    assert passable[1, 2] and passable[2, 1]
    assert passable[1, 1] ^ passable[2, 2]  # exactly one of the two corner cells is opened
    assert np.isfinite(distance_fields(passable, np.array([[1, 2]]), 1.0)[0, 2, 1])


def test_region_box() -> None:
    mask = np.zeros((20, 30), dtype=bool)
    mask[5:8, 10:12] = True
    assert region_box(mask, 2) == Box(3, 10, 8, 14)
    assert region_box(mask, 2, np.array([[15, 1]])) == Box(3, 18, 0, 14)
    assert region_box(mask, 50) == Box(0, 20, 0, 30)
    assert region_box(np.zeros_like(mask), 2) == Box(0, 20, 0, 30)
    assert region_box(mask, 0).shape == (3, 2)


# ---------------------------------------------------------------------------------- distances


@pytest.mark.parametrize("method", METHODS)
def test_empty_room_is_euclidean(method: Method) -> None:
    shape, source = (81, 81), (40, 40)
    dist = distance_fields(np.ones(shape, dtype=bool), np.array([source]), CELL_M, method=method)[0]
    euclid = _euclid(shape, source) * CELL_M
    assert dist[source] == 0.0
    far = euclid > 1.0
    rel = np.abs(dist[far] - euclid[far]) / euclid[far]
    assert rel.mean() < 0.01 and rel.max() < 0.02


def test_fmm_exact_next_to_the_source() -> None:
    dist = distance_fields(np.ones((5, 5), dtype=bool), np.array([[2, 2]]), 1.0)[0]
    assert dist[2, 3] == dist[1, 2] == 1.0
    np.testing.assert_allclose(dist[[1, 1, 3, 3], [1, 3, 1, 3]], np.sqrt(2.0), rtol=1e-6)


@pytest.mark.parametrize("method", METHODS)
def test_around_a_wall_through_a_door(method: Method) -> None:
    passable = np.ones((41, 41), dtype=bool)
    passable[20, :] = False
    passable[20, 10:16] = True  # a door, cells 10..15 of the wall row
    dist = distance_fields(passable, np.array([[10, 30]]), 1.0, method=method)[0]
    via_corner = 2 * np.hypot(10, 15)  # (10, 30) -> door corner (20, 15) -> (30, 30)
    assert via_corner * 0.99 <= dist[30, 30] <= via_corner * 1.04
    assert dist[30, 30] > 20.0 * 1.5  # much longer than the straight line
    assert np.isinf(dist[20, 0]) and np.isinf(dist[20, 30])  # impassable cells
    passable[20, 10:16] = False  # close the door
    closed = distance_fields(passable, np.array([[10, 30]]), 1.0, method=method)[0]
    assert np.isinf(closed[21:]).all() and np.isfinite(closed[:20]).all()


@pytest.mark.parametrize("method", METHODS)
def test_degenerate_sources(method: Method) -> None:
    passable = np.ones((10, 10), dtype=bool)
    passable[4:7, 4:7] = False
    on_wall, beside = distance_fields(passable, np.array([[4, 5], [0, 0]]), 1.0, method=method)
    assert on_wall[4, 5] == 0.0 and np.isfinite(on_wall[3, 5]) and np.isinf(on_wall[5, 5])
    assert np.isinf(beside[4, 5])  # the wall cell is passable for its own source only
    at = distances_to(passable, np.array([[4, 5], [0, 0]]), np.array([[4, 5], [5, 5], [9, 9]]), 1.0, method=method)
    assert at[0, 0] == 0.0 and np.isinf(at[0, 1]) and np.isinf(at[1, :2]).all() and np.isfinite(at[:, 2]).all()
    nothing = distance_fields(np.zeros((6, 6), dtype=bool), np.array([[2, 3], [0, 0]]), 1.0, method=method)
    assert nothing[0, 2, 3] == 0.0 and nothing[1, 0, 0] == 0.0
    assert np.isinf(nothing).sum() == 2 * 36 - 2
    with pytest.raises(ValueError, match="outside"):
        distance_fields(passable, np.array([[10, 0]]), 1.0, method=method)
    with pytest.raises(ValueError, match="outside"):
        distance_fields(passable, np.array([[0, -1]]), 1.0, method=method)


def test_unknown_method() -> None:
    with pytest.raises(ValueError, match="method"):
        distance_fields(np.ones((3, 3), dtype=bool), np.array([[1, 1]]), 1.0, method="dijkstra")  # type: ignore[arg-type]


@cache
def _bundled(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    scene = load_scene(name)
    cells = np.argwhere(scene.free)
    sources = cells[np.random.default_rng(0).choice(len(cells), 4, replace=False)]
    fast = distance_fields(scene.free, sources, scene.cell_m, method="fmm")
    ref = distance_fields(scene.free, sources, scene.cell_m, method="skfmm")
    return sources, fast, ref, scene.cell_m


@pytest.mark.parametrize("name", ["robotathome_sarmis", "bormann_lab_ipa_rooms3"])
def test_fmm_agrees_with_skfmm_on_bundled_maps(name: str) -> None:
    _, fast, ref, _ = _bundled(name)
    np.testing.assert_array_equal(np.isfinite(fast), np.isfinite(ref))
    far = np.isfinite(ref) & (ref > 1.0)
    rel = np.abs(fast[far] - ref[far]) / ref[far]
    assert rel.mean() < 0.01, rel.mean()
    assert rel.max() < 0.05, rel.max()


def test_distances_to_equals_the_fields_and_is_deterministic() -> None:
    sources, fields, _, cell_m = _bundled("robotathome_sarmis")
    free = load_scene("robotathome_sarmis").free
    cells = np.argwhere(free)
    goals = cells[np.random.default_rng(1).choice(len(cells), 30, replace=False)]
    at = distances_to(free, sources, goals, cell_m)
    assert at.shape == (4, 30) and at.dtype == np.float32
    np.testing.assert_array_equal(at, fields[:, goals[:, 0], goals[:, 1]])
    np.testing.assert_array_equal(at, distances_to(free, sources, goals, cell_m))
    np.testing.assert_array_equal(distances_to(free, sources, goals[:0], cell_m), np.zeros((4, 0)))


def test_distance_field_stops_at_the_given_cells() -> None:
    passable = np.ones((30, 40), dtype=bool)
    full = distance_field(passable, np.array([5, 5]), CELL_M)
    np.testing.assert_array_equal(full, distance_fields(passable, np.array([[5, 5]]), CELL_M)[0])
    part = distance_field(passable, np.array([5, 5]), CELL_M, stop_at=np.array([[5, 15]]))
    assert part[5, 15] == full[5, 15]
    settled = np.isfinite(part)
    np.testing.assert_array_equal(part[settled], full[settled])
    assert np.isinf(part[25, 35])  # far beyond the stop cell: never reached
    assert (full[settled] <= full[5, 15] + 2 * CELL_M).all()


@cache
def _explored_map() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A real map part way through a bounce walk: explored, occupied, robot cells."""
    from areasearch.config import WorldConfig
    from areasearch.sim.actions import bounce_walk
    from areasearch.sim.world import World

    scene = load_scene("robotathome_sarmis")
    world = World(WorldConfig(num_robots=4))
    rng = np.random.default_rng(1)
    world.reset(scene, rng)
    collided = np.zeros(4, dtype=bool)
    turning = np.zeros(4, dtype=np.int64)
    for _ in range(300):
        collided = world.step(bounce_walk(collided, turning, rng)).collided
    assert world.mapper is not None
    cells = scene.world_to_cell(world.poses[:, :2])
    return world.mapper.explored.copy(), world.mapper.occupied.copy(), cells


@pytest.mark.parametrize("margin_m", [None, 0.0, 0.5, 4.0])
def test_window_grid_is_the_planning_grid_cut_to_the_window(margin_m: float | None) -> None:
    """The 64-cells-a-word window grid equals the whole-map planning grid on any window that keeps
    clear of the map's pinches at its edge, with the inflation precomputed or not, and with a
    collision map."""
    from areasearch.planning.frontiers import frontier_mask

    explored, occupied, cells = _explored_map()
    h, w = explored.shape
    whole = planning_grid(
        explored, occupied, CELL_M, RADIUS_M, keep_free=cells, unknown_margin_m=margin_m,
        margin_from=frontier_mask(explored, occupied),
    )  # fmt: skip
    inflated = InflatedObstacles(explored.shape, CELL_M, RADIUS_M).update(occupied)
    rng = np.random.default_rng(0)
    blocked = rng.random(explored.shape) < 0.01
    boxes = [Box(0, h, 0, w)] + [Box(int(y), int(y) + 90, int(x), int(x) + 70) for y, x in rng.integers(0, 150, (6, 2))]
    for box in boxes:
        for given in (None, inflated):
            passable, frontier = window_grid(
                explored, occupied, box, CELL_M, RADIUS_M, unknown_margin_m=margin_m, keep_free=cells, inflated=given
            )
            np.testing.assert_array_equal(frontier, frontier_mask(explored, occupied)[box.slices])
            inner = (slice(1, -1), slice(1, -1))  # a pinch opened across the window's edge may differ
            np.testing.assert_array_equal(passable[inner], whole[box.slices][inner])
        masked, _ = window_grid(
            explored, occupied, box, CELL_M, RADIUS_M, unknown_margin_m=margin_m, keep_free=cells,
            impassable=blocked, inflated=inflated,
        )  # fmt: skip
        expected = whole[box.slices] & ~blocked[box.slices]
        local = cells - box.origin
        inside = ((local >= 0) & (local < box.shape)).all(axis=1)
        expected[local[inside, 0], local[inside, 1]] = True
        np.testing.assert_array_equal(masked[inner], expected[inner])
    np.testing.assert_array_equal(window_grid(explored, occupied, boxes[0], CELL_M, RADIUS_M,
                                              unknown_margin_m=margin_m, keep_free=cells)[0], whole)  # fmt: skip


def test_inflated_obstacles_follow_the_map() -> None:
    """Kept up to date cell by cell, the inflation is the distance transform rule of the map now."""
    explored, occupied, _ = _explored_map()
    kept = InflatedObstacles(explored.shape, CELL_M, RADIUS_M)
    grown = np.zeros_like(occupied)
    for columns in (80, 160, occupied.shape[1]):  # obstacles appear
        grown[:, :columns] = occupied[:, :columns]
        expected = ndimage.distance_transform_edt(~grown) * CELL_M <= clearance_threshold_m(CELL_M, RADIUS_M)
        np.testing.assert_array_equal(kept.update(grown), expected)
    grown[:, 100:] = False  # and disappear (a reset, an edited map)
    expected = ndimage.distance_transform_edt(~grown) * CELL_M <= clearance_threshold_m(CELL_M, RADIUS_M)
    np.testing.assert_array_equal(kept.update(grown), expected)
