"""Tests of :mod:`areasearch.envs.observation`: the pooled map channels, padding, masks and history of the
goal planners' observation on small hand-built inputs, and the simulator and a real map (assign)
giving the same observation of the same map state."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from areasearch.config import DecisionConfig, SearchConfig, override
from areasearch.envs.goal import MAP_CHANNELS as ENV_MAP_CHANNELS
from areasearch.envs.goal import AreaSearchEnv
from areasearch.envs.observation import MAP_CHANNELS, build_observation, map_scale, pool_map_channels
from areasearch.planning.candidates import CandidateKind, Candidates
from areasearch.service.assign import OccupancyMap, build_decision

ROBOTS, GOALS_CH, HIST_CH, FRONT, TARGETS, OBST, EXPL = 0, 6, 1, 2, 3, 4, 5


def _config(max_candidates: int = 4, history: int = 3, map_cells: int = 4, map_downsample: int = 2) -> SearchConfig:
    return override(
        SearchConfig(),
        **{
            "candidates.max_candidates": max_candidates,
            "decisions.history": history,
            "decisions.map_cells": map_cells,
            "decisions.map_downsample": map_downsample,
        },
    ).validate()


def _candidates(distance_m: np.ndarray) -> Candidates:
    """Two candidates: a frontier node at (1, 2) and a target node at (5, 4)."""
    return Candidates(
        cells=np.array([[1, 2], [5, 4]], dtype=np.int64),
        kind=np.array([CandidateKind.FRONTIER, CandidateKind.TARGET], dtype=np.int8),
        size=np.array([7, 1], dtype=np.int64),
        gain=np.array([12.5, 0.0], dtype=np.float32),
        target_id=np.array([-1, 0], dtype=np.int64),
        distance_m=np.asarray(distance_m, dtype=np.float32),
        offset_m=np.zeros(2, dtype=np.float32),
    )


def _grids(h: int = 6, w: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """explored, occupied, targets (h, w): the western 3 columns explored, an obstacle at (0, 0),
    a target at (5, 2)."""
    explored = np.zeros((h, w), dtype=bool)
    explored[:, :3] = True
    occupied = np.zeros((h, w), dtype=bool)
    occupied[0, 0] = True
    targets = np.zeros((h, w), dtype=bool)
    targets[5, 2] = True
    return explored, occupied, targets


def test_map_channels_are_one_tuple_re_exported_by_the_environment() -> None:
    assert ENV_MAP_CHANNELS is MAP_CHANNELS
    assert MAP_CHANNELS.index("robots") == ROBOTS and MAP_CHANNELS.index("history_goals") == GOALS_CH
    assert MAP_CHANNELS.index("explored") == EXPL and MAP_CHANNELS.index("frontiers") == FRONT


def test_map_scale_is_the_downsampling_unless_the_map_needs_more() -> None:
    d = DecisionConfig(map_cells=128, map_downsample=4)
    assert map_scale((100, 512), d) == 4
    assert map_scale((513, 20), d) == 5  # ceil(513 / 128)
    assert map_scale((1024, 1024), d) == 8


def test_pooling_takes_the_max_and_the_explored_share() -> None:
    explored, occupied, targets = _grids()
    visited = np.zeros_like(explored)
    visited[3, 1] = True
    out = pool_map_channels(explored, occupied, targets, visited, np.zeros((0, 2)), np.zeros((0, 2)), 2, 3)
    assert out.shape == (len(MAP_CHANNELS), 3, 3) and out.dtype == np.float32
    # explored: blocks of columns 0-1 fully explored, of columns 2-3 half, of columns 4-5 not at all
    assert out[EXPL].tolist() == [[1.0, 0.5, 0.0]] * 3
    assert out[OBST].tolist() == [[1, 0, 0], [0, 0, 0], [0, 0, 0]]  # one cell of a block is enough
    assert out[TARGETS].tolist() == [[0, 0, 0], [0, 0, 0], [0, 1, 0]]
    assert out[HIST_CH].tolist() == [[0, 0, 0], [1, 0, 0], [0, 0, 0]]
    # frontiers: the explored cells of column 2, beside the unknown column 3
    assert out[FRONT].tolist() == [[0, 1, 0]] * 3
    assert not out[ROBOTS].any() and not out[GOALS_CH].any()


def test_a_frontier_needs_an_unknown_neighbour_inside_the_grid_and_a_free_cell() -> None:
    explored = np.ones((4, 4), dtype=bool)  # all known: the grid's edge is no frontier
    occupied = np.zeros((4, 4), dtype=bool)
    none = np.zeros((4, 4), dtype=bool)
    out = pool_map_channels(explored, occupied, none, none, np.zeros((0, 2)), np.zeros((0, 2)), 1, 4)
    assert not out[FRONT].any() and out[EXPL].all()
    explored[0, 3] = False
    occupied[1, 3] = True  # an obstacle beside the unknown cell is no frontier
    out = pool_map_channels(explored, occupied, none, none, np.zeros((0, 2)), np.zeros((0, 2)), 1, 4)
    assert np.argwhere(out[FRONT]).tolist() == [[0, 2]]


def test_the_map_is_zero_padded_and_cut_to_the_canvas() -> None:
    explored, occupied, targets = _grids()
    visited = np.zeros_like(explored)
    robots = np.array([[0, 0], [5, 5]])
    big = pool_map_channels(explored, occupied, targets, visited, robots, np.zeros((0, 2)), 2, 5)
    assert big.shape == (7, 5, 5)
    assert not big[:, 3:].any() and not big[:, :, 3:].any()  # beyond the 6 x 6 map: zero
    assert big[ROBOTS].sum() == 2 and big[ROBOTS, 2, 2] == 1
    small = pool_map_channels(explored, occupied, targets, visited, robots, np.zeros((0, 2)), 2, 2)
    assert np.array_equal(small, big[:, :2, :2])  # cells beyond a 2 x 2 canvas are cut off
    assert small[ROBOTS].sum() == 1


def test_robots_and_goals_skip_rows_of_minus_one() -> None:
    explored, occupied, targets = _grids()
    visited = np.zeros_like(explored)
    goals = np.array([[-1, -1], [4.0, 1.0], [-1, -1]], dtype=np.float32)
    robots = np.array([[1, 1], [-1, -1]])
    out = pool_map_channels(explored, occupied, targets, visited, robots, goals, 2, 3)
    assert np.argwhere(out[GOALS_CH]).tolist() == [[2, 0]]
    assert np.argwhere(out[ROBOTS]).tolist() == [[0, 0]]


def test_nothing_explored_still_shows_the_robots() -> None:
    none = np.zeros((6, 6), dtype=bool)
    out = pool_map_channels(none, none, none, none, np.array([[3, 3]]), np.array([[1, 1]]), 2, 3)
    assert np.argwhere(out[ROBOTS]).tolist() == [[1, 1]] and np.argwhere(out[GOALS_CH]).tolist() == [[0, 0]]
    assert not out[1:6].any()


def test_the_observation_pads_candidates_and_masks_them() -> None:
    explored, occupied, targets = _grids()
    cfg = _config()
    distances = np.array([[1.5, np.inf], [2.0, 3.0]])
    cells = np.array([[1, 1], [4, 1]])
    empty = np.zeros((0, 2, 2), dtype=np.float32)

    def observe(yaw: np.ndarray, progress: float, **extra: Any) -> dict[str, np.ndarray]:
        return build_observation(
            _candidates(distances),
            cells,
            yaw,
            explored,
            occupied,
            targets,
            empty,
            empty,
            cell_m=0.05,
            progress=progress,
            config=cfg,
            **extra,
        )

    obs = observe(np.array([0.5, -1.0]), 0.25)
    assert obs["candidates"].tolist() == [[1, 2, 0, 7, 12.5], [5, 4, 1, 1, 0], [0] * 5, [0] * 5]
    assert obs["candidate_mask"].tolist() == [1, 1, 0, 0]
    assert obs["distances"].tolist() == [[1.5, np.inf, np.inf, np.inf], [2.0, 3.0, np.inf, np.inf]]
    assert obs["action_mask"].tolist() == [[1, 0, 0, 0], [1, 1, 0, 0]]  # the reachable ones
    assert obs["robots"].tolist() == [[1, 1, 0.5], [4, 1, -1.0]]
    assert obs["map_scale"].tolist() == [2.0] and obs["cell_m"].tolist() == [np.float32(0.05)]
    assert obs["progress"].tolist() == [0.25]
    assert not obs["history_mask"].any() and not obs["history_robots"].any() and not obs["history_goals"].any()
    # channel 1 by default: the robots' own cells
    assert np.array_equal(obs["map"][HIST_CH], obs["map"][ROBOTS])
    # the dtypes and shapes of the environment's observation space
    space = AreaSearchEnv(map="procedural:small", num_robots=2, config=cfg).observation_space
    assert obs.keys() == space.spaces.keys()
    for key, value in obs.items():
        assert value.shape == space[key].shape and value.dtype == space[key].dtype, key

    allowed = np.array([[False, False], [True, False]])
    obs = observe(np.zeros(2), 0.0, allowed=allowed)
    assert obs["action_mask"].tolist() == [[0, 0, 0, 0], [1, 0, 0, 0]]


def test_history_is_padded_with_minus_one_then_zero() -> None:
    explored, occupied, targets = _grids()
    cells = np.array([[1, 1], [4, 1]])
    past_robots = np.array([[[0, 1], [3, 1]], [[0, 0], [-1, -1]]], dtype=np.float32)  # two decisions
    past_goals = np.array([[[5, 4], [-1, -1]]], dtype=np.float32)  # one

    def observe(**extra: Any) -> dict[str, np.ndarray]:
        return build_observation(
            _candidates(np.ones((2, 2))),
            cells,
            np.zeros(2),
            explored,
            occupied,
            targets,
            past_robots,
            past_goals,
            cell_m=0.05,
            progress=0.0,
            config=_config(),
            **extra,
        )

    obs = observe()
    assert obs["history_mask"].tolist() == [1, 1, 0]
    assert obs["history_robots"].tolist() == [[[0, 1], [3, 1]], [[0, 0], [-1, -1]], [[0, 0], [0, 0]]]
    assert obs["history_goals"].tolist() == [[[5, 4], [-1, -1]], [[-1, -1], [-1, -1]], [[0, 0], [0, 0]]]
    assert np.argwhere(obs["map"][GOALS_CH]).tolist() == [[2, 2]]
    # channel 1 by default: current cells (0, 0), (2, 0) and past cells (0, 0), (1, 0)
    assert np.argwhere(obs["map"][HIST_CH]).tolist() == [[0, 0], [1, 0], [2, 0]]
    # a trajectory given instead
    visited = np.zeros_like(explored)
    visited[5, 0] = True
    obs = observe(visited=visited)
    assert np.argwhere(obs["map"][HIST_CH]).tolist() == [[2, 0]]


def test_too_many_candidates_or_decisions_are_refused() -> None:
    explored, occupied, targets = _grids()
    cells = np.array([[1, 1], [4, 1]])
    empty = np.zeros((0, 2, 2), dtype=np.float32)
    args = (np.zeros(2), explored, occupied, targets)
    with pytest.raises(ValueError, match="max_candidates"):
        build_observation(
            _candidates(np.ones((2, 2))), cells, *args, empty, empty, cell_m=0.05, progress=0, config=_config(1)
        )
    deep = np.zeros((4, 2, 2), dtype=np.float32)
    with pytest.raises(ValueError, match=r"decisions\.history"):
        build_observation(
            _candidates(np.ones((2, 2))), cells, *args, deep, empty, cell_m=0.05, progress=0, config=_config()
        )


def test_the_simulator_and_a_real_map_observe_one_map_state_alike(
    sarmis_played: tuple[AreaSearchEnv, dict[str, Any]],
) -> None:
    """The team's own map and history, given to :func:`~areasearch.service.assign.build_decision` as a user's
    map, give the simulator's observation; only the historical positions differ: the simulator
    marks the robots' whole trajectory, a map alone only the robots' decision cells."""
    env, obs = sarmis_played
    world = env.world
    assert world.scene is not None and world.mapper is not None and env.planner is not None
    mapper, scene = world.mapper, world.scene
    # no bump marks (nor failed or exhausted goals: the candidates compare equal below), nothing the
    # simulator knows beyond the map
    assert not env.planner.bumps.any() and not env._exhausted
    grid = OccupancyMap(mapper.explored & ~mapper.occupied, mapper.occupied, scene.cell_m, scene.origin_xy)
    depth = int(obs["history_mask"].sum())
    past = [[grid.cell_to_world(obs["history_robots"][i, r]).tolist() for i in range(depth)] for r in range(3)]
    goals = [
        [
            None if obs["history_goals"][i, r, 0] < 0 else grid.cell_to_world(obs["history_goals"][i, r]).tolist()
            for i in range(depth)
        ]
        for r in range(3)
    ]
    pending = np.flatnonzero(world.discovered & ~world.covered)
    decision = build_decision(
        grid, world.poses, world.targets_xy[pending], past, goals, progress=float(obs["progress"][0])
    )
    got = decision.obs
    assert got.keys() == obs.keys()
    assert len(decision.candidates) == int(obs["candidate_mask"].sum())
    for key in obs:
        if key != "map":
            assert got[key].dtype == obs[key].dtype and np.array_equal(got[key], obs[key]), key
    for channel in range(len(MAP_CHANNELS)):
        if channel != HIST_CH:
            assert np.array_equal(got["map"][channel], obs["map"][channel]), MAP_CHANNELS[channel]
    # historical positions: the decision cells lie on the trajectory, which holds more
    assert (obs["map"][HIST_CH] >= got["map"][HIST_CH]).all()
    assert obs["map"][HIST_CH].sum() > got["map"][HIST_CH].sum() > 0
