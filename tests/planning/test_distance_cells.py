"""The candidates' distances marched on blocks of cells (``candidates.distance_cell_m``): the block
grid, the distances it gives against the map's own cells, and the paths read off its fields."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from areasearch.config import SearchConfig, WorldConfig, override
from areasearch.errors import ConfigError
from areasearch.planning.candidates import (
    CandidateParams,
    Candidates,
    distance_block,
    extract_candidates,
    extract_from_world,
    search_candidate_params,
)
from areasearch.planning.geodesic import block_grid
from areasearch.planning.paths import descend, plan_path, route_path
from areasearch.sim.scene import load_scene
from areasearch.sim.world import World

CELL_M = 0.05
RADIUS_M = 0.18


# ---------------------------------------------------------------------------------- the block grid


def test_block_grid_by_hand() -> None:
    passable = np.array(
        [
            [0, 0, 1, 0, 0],
            [0, 0, 0, 0, 0],
            [0, 0, 0, 0, 1],
        ],
        dtype=bool,
    )
    np.testing.assert_array_equal(block_grid(passable, 2), [[False, True, False], [False, False, True]])
    np.testing.assert_array_equal(block_grid(passable, 3), [[True, True]])
    np.testing.assert_array_equal(block_grid(passable, 1), passable)
    assert block_grid(passable, 1) is not passable
    with pytest.raises(ValueError, match="at least 1"):
        block_grid(passable, 0)


@pytest.mark.parametrize("k", [2, 3, 4])
def test_every_passable_cell_lies_in_a_passable_block_and_only_those(k: int) -> None:
    rng = np.random.default_rng(k)
    passable = rng.random((37, 29)) < 0.1
    blocks = block_grid(passable, k)
    assert blocks.shape == (-(-37 // k), -(-29 // k))
    ys, xs = np.nonzero(passable)
    assert blocks[ys // k, xs // k].all()
    by, bx = np.nonzero(blocks)
    assert all(passable[y * k : (y + 1) * k, x * k : (x + 1) * k].any() for y, x in zip(by, bx, strict=True))


def test_the_block_of_a_distance_cell() -> None:
    assert distance_block(0.0, 0.05) == 1
    assert distance_block(0.1, 0.05) == 2
    assert distance_block(0.12, 0.05) == 2
    assert distance_block(0.025, 0.05) == 1
    assert distance_block(0.1, 0.025) == 4
    assert distance_block(0.1, 0.1) == 1
    cfg = override(SearchConfig(), **{"candidates.distance_cell_m": 0.1})
    assert search_candidate_params(cfg, 0.05).distance_block == 2
    assert search_candidate_params(SearchConfig(), 0.05).distance_block == 1
    for bad in (-0.1, 2.0, float("nan")):
        with pytest.raises(ConfigError, match=r"candidates\.distance_cell_m"):
            override(SearchConfig(), **{"candidates.distance_cell_m": bad}).validate()


# ---------------------------------------------------------------------------------- a real world


@cache
def _world(steps: int) -> World:
    world = World(WorldConfig(num_robots=3))
    world.reset(load_scene("bormann_lab_ipa"), np.random.default_rng(1))
    for _ in range(steps):
        world.step(np.array([0, 0, 2]))
    return world


def _pair(steps: int) -> tuple[Candidates, Candidates]:
    world = _world(steps)
    return (
        extract_from_world(world, keep_routes=True),
        extract_from_world(world, keep_routes=True, distance_block=2),
    )


@pytest.mark.parametrize("steps", [20, 120])
def test_coarse_distances_stay_near_the_fine_ones_and_lose_no_goal(steps: int) -> None:
    fine, coarse = _pair(steps)
    assert coarse.routes is not None and coarse.routes.block == 2
    assert coarse.routes.fields.shape[1:] == tuple(-(-s // 2) for s in coarse.routes.passable.shape)
    # the same nodes: no reachable frontier dropped, none added
    np.testing.assert_array_equal(fine.cells, coarse.cells)
    np.testing.assert_array_equal(np.isfinite(fine.distance_m), np.isfinite(coarse.distance_m))
    reach = np.isfinite(fine.distance_m)
    assert reach.sum() > 10
    error = np.abs(coarse.distance_m[reach] - fine.distance_m[reach])
    # a robot and a goal each at most half a block's diagonal from their block's centre, plus the
    # scheme's own error on the coarser grid
    assert error.max() <= 0.5, error.max()
    assert np.median(error) <= 0.1, np.median(error)


def _steps_ok(path: np.ndarray) -> bool:
    return bool(np.all(np.abs(np.diff(path, axis=0)).max(axis=1) == 1))


def _length(path: np.ndarray) -> float:
    return float(np.hypot(*np.diff(path, axis=0).T).sum())


def test_paths_off_coarse_fields_are_paths_on_the_map_cells() -> None:
    fine, coarse = _pair(120)
    assert fine.routes is not None and coarse.routes is not None
    passable = coarse.routes.passable
    checked = 0
    for r in range(3):
        reach = np.flatnonzero(np.isfinite(fine.distance_m[r]))
        for j in (reach[np.argmin(fine.distance_m[r, reach])], reach[np.argmax(fine.distance_m[r, reach])]):
            goal = fine.cells[j] - coarse.routes.box.origin
            path = route_path(coarse.routes, r, goal)
            exact = route_path(fine.routes, r, goal)
            assert len(path) > 0 and len(exact) > 0
            np.testing.assert_array_equal(path[0], coarse.routes.robots[r])
            np.testing.assert_array_equal(path[-1], goal)
            np.testing.assert_array_equal(exact[0], path[0])
            assert passable[path[1:, 0], path[1:, 1]].all()  # the robot's own cell is forced passable
            assert _steps_ok(path)
            assert _length(path) <= 1.02 * _length(exact) + 1.0
            checked += 1
    assert checked >= 3


def test_fine_route_is_the_steepest_descent_reversed() -> None:
    fine, _ = _pair(20)
    assert fine.routes is not None
    j = int(np.flatnonzero(np.isfinite(fine.distance_m[0]))[0])
    goal = fine.cells[j] - fine.routes.box.origin
    field = fine.routes.fields[0]
    np.testing.assert_array_equal(route_path(fine.routes, 0, goal), descend(field, *goal, field.size)[::-1])


# -------------------------------------------------------------------------------- blocks joining what the map does not


def _thin_wall() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 60 x 80 room, all explored and free, split by a wall one cell thick (the action planner's
    bump marks, ``impassable``: not inflated) from the top down to row 50; a robot left of it, a
    target right of it."""
    explored = np.ones((60, 80), dtype=bool)
    explored[0, :] = explored[-1, :] = explored[:, 0] = explored[:, -1] = True
    occupied = np.zeros_like(explored)
    occupied[0, :] = occupied[-1, :] = occupied[:, 0] = occupied[:, -1] = True
    impassable = np.zeros_like(explored)
    impassable[:50, 41] = True
    return explored, occupied, impassable


def test_a_wall_thinner_than_a_block_gives_a_route_round_it() -> None:
    explored, occupied, impassable = _thin_wall()
    robot, target = np.array([[20, 36]]), np.array([[20, 46]])
    found = {
        k: extract_candidates(
            explored,
            occupied,
            robot,
            target,
            np.array([0]),
            CandidateParams(cell_m=CELL_M, radius_m=RADIUS_M, keep_routes=True, distance_block=k),
            impassable=impassable,
        )
        for k in (1, 2)
    }
    fine, coarse = found[1], found[2]
    assert coarse.routes is not None and fine.routes is not None
    # the blocks see through the wall: the coarse distance is the straight one, the fine one goes round
    assert coarse.distance_m[0, -1] < 0.6 < 2.0 < fine.distance_m[0, -1]
    goal = coarse.cells[-1] - coarse.routes.box.origin
    path = route_path(coarse.routes, 0, goal)
    passable = coarse.routes.passable
    assert len(path) > 0 and passable[path[1:, 0], path[1:, 1]].all() and _steps_ok(path)
    assert (path[:, 0] >= 50).any()  # round the end of the wall
    np.testing.assert_allclose(_length(path), _length(plan_path(passable, path[0], goal, CELL_M)), rtol=1e-6)


# ---------------------------------------------------------------------------------- in the environment


def _episode(**settings: float) -> tuple[list[np.ndarray], dict[str, float]]:
    from areasearch.envs.goal import AreaSearchEnv, decide, nearest_candidate

    env = AreaSearchEnv(map="robotathome_sarmis", num_robots=3, seed=4, max_steps=600, **settings)
    env.reset(seed=4)
    assert env.candidates.routes is not None
    assert env.candidates.routes.block == (2 if settings else 1)
    distances, done, info = [], False, {}
    while not done:
        distances.append(env.candidates.distance_m.copy())
        _, _, terminated, truncated, info = env.step(decide(env, nearest_candidate))
        done = terminated or truncated
    return distances, info


def test_an_episode_on_coarse_distances_is_reproducible_and_searches() -> None:
    coarse = {"candidates.distance_cell_m": 0.1}
    first, info = _episode(**coarse)
    again, info_again = _episode(**coarse)
    assert len(first) == len(again) and all(np.array_equal(a, b) for a, b in zip(first, again, strict=True))
    assert info == info_again
    fine, fine_info = _episode()
    assert not np.array_equal(first[0], fine[0])  # the setting reaches the planner's distances
    assert info["explored_pct"] > 0.5 * fine_info["explored_pct"] > 0
