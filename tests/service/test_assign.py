"""Tests of :mod:`areasearch.service.assign` and ``areasearch assign``: goals on a user's own partial map, in
the map frame, from the given map only; every map form read alike; bad poses refused."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from PIL import Image

from areasearch.envs.goal import AreaSearchEnv
from areasearch.errors import ConfigError, MapError
from areasearch.planners import PLANNERS, make_planner
from areasearch.planning.candidates import CandidateParams, extract_candidates
from areasearch.service.assign import (
    OccupancyMap,
    assign_goals,
    build_decision,
    load_occupancy,
    occupancy_from_array,
    read_robots,
    read_targets,
    save_occupancy_yaml,
)

CliRunner = Callable[..., subprocess.CompletedProcess[str]]

HalfKnown = Callable[..., OccupancyMap]

CELL = 0.1


def _path_ok(grid: OccupancyMap, a_path: list[tuple[float, float]], step_m: float = 0.25) -> None:
    points = np.asarray(a_path)
    gaps = np.hypot(*np.diff(points, axis=0).T)
    assert (gaps <= step_m * np.sqrt(2) + CELL).all()
    cells = grid.world_to_cell(points)
    assert grid.inside(cells).all()
    assert not grid.occupied[cells[:, 0], cells[:, 1]].any()


# ---------------------------------------------------------------------------------- goals


def test_greedy_goes_to_the_frontier_of_the_given_map(half_known: HalfKnown) -> None:
    grid = half_known()
    (a,) = assign_goals(grid, [(1.05, 1.55, 0.0)], method="greedy")
    assert a.kind == "frontier" and a.target is None
    assert a.goal_xy is not None
    assert a.goal_xy[0] == pytest.approx(2.95)  # the last known-free column
    assert 0.35 < a.goal_xy[1] < 2.65
    assert a.distance_m is not None and 1.85 < a.distance_m < 2.2
    assert a.path_xy[0] == (1.05, 1.55) and a.path_xy[-1] == a.goal_xy
    xs = [p[0] for p in a.path_xy]
    assert xs == sorted(xs)  # straight east
    _path_ok(grid, a.path_xy)


def test_the_origin_is_honoured(half_known: HalfKnown) -> None:
    poses = [(1.05, 1.55, 0.0), (1.05, 0.75, 1.0)]
    base = assign_goals(half_known(), poses, method="hungarian")
    shift = (-12.5, 3.25)
    moved = assign_goals(half_known(shift), [(x + shift[0], y + shift[1], t) for x, y, t in poses], method="hungarian")
    for a, b in zip(base, moved, strict=True):
        assert (a.kind, a.target) == (b.kind, b.target)
        assert a.distance_m == pytest.approx(b.distance_m)
        assert np.allclose(np.asarray(b.path_xy) - shift, a.path_xy)


def test_a_near_target_wins_and_is_named_by_its_index(half_known: HalfKnown) -> None:
    grid = half_known()
    targets = [(2.5, 2.5), (1.55, 1.55)]
    (a,) = assign_goals(grid, [(1.05, 1.55, 0.0)], method="greedy", targets=targets)
    assert a.kind == "target" and a.target == 1
    assert a.goal_xy is not None and np.hypot(a.goal_xy[0] - 1.55, a.goal_xy[1] - 1.55) <= 0.3


def test_a_finished_map_gives_no_goal() -> None:
    data = np.zeros((20, 20), dtype=np.int8)
    data[[0, -1], :] = 100
    data[:, [0, -1]] = 100
    out = assign_goals(occupancy_from_array(data, CELL), [(0.5, 0.5, 0.0), (1.5, 1.5, 0.0)], method="voronoi")
    assert [(a.kind, a.goal_xy, a.path_xy, a.distance_m) for a in out] == [("none", None, [], None)] * 2


def test_unknown_floor_under_a_robot_is_not_a_frontier(half_known: HalfKnown) -> None:
    """A fresh SLAM map has not seen the floor under the robot: that hole must not become the goal."""
    grid = half_known()
    free = grid.free.copy()
    free[13:18, 8:13] = False  # unknown disc under the robot at (1.05, 1.55)
    holed = OccupancyMap(free, grid.occupied, CELL)
    (a,) = assign_goals(holed, [(1.05, 1.55, 0.0)], method="greedy")
    assert a.kind == "frontier" and a.goal_xy is not None and a.goal_xy[0] == pytest.approx(2.95)


def test_a_robot_closer_to_a_wall_than_its_clearance_still_plans(half_known: HalfKnown) -> None:
    grid = half_known()
    (a,) = assign_goals(grid, [(1.05, 0.12, 0.0)], method="greedy")  # 2 cm from the wall's cell face
    assert a.kind == "frontier" and a.distance_m is not None
    assert a.path_xy[0] == (1.05, 0.12)
    _path_ok(grid, a.path_xy)


@pytest.mark.parametrize("method", sorted(PLANNERS))
def test_every_planner_gives_reachable_goals(method: str, half_known: HalfKnown) -> None:
    grid = half_known()
    poses = [(1.05, 1.55, 0.0), (0.55, 0.55, 0.5), (0.55, 2.45, -0.5)]
    out = assign_goals(grid, poses, method=method, targets=[(2.0, 0.6)], seed=3)
    assert [a.robot for a in out] == [0, 1, 2]
    for a in out:
        assert a.kind in ("frontier", "target")
        assert a.distance_m is not None and np.isfinite(a.distance_m)
        assert a.goal_xy is not None and grid.free[tuple(grid.world_to_cell(a.goal_xy))]
        _path_ok(grid, a.path_xy)
    again = assign_goals(grid, poses, method=method, targets=[(2.0, 0.6)], seed=3)
    assert again == out


@pytest.mark.slow
def test_a_planner_object_and_learned_weights_are_accepted(tmp_path: Path, half_known: HalfKnown) -> None:
    from areasearch.models.network import DAHGNN
    from areasearch.models.network_config import NetworkConfig
    from areasearch.models.weights import save_policy

    grid = half_known()
    config = NetworkConfig.ncm()
    save_policy(tmp_path / "policy", DAHGNN(config), config)
    poses = [(1.05, 1.55, 0.0), (0.55, 0.55, 0.5)]
    loaded = assign_goals(grid, poses, "ncm-untrained", planner_settings={"weights": str(tmp_path / "policy")})
    planner = make_planner("ncm-untrained", weights=str(tmp_path / "policy"))
    assert assign_goals(grid, poses, planner) == loaded
    assert all(a.kind == "frontier" for a in loaded)


# ---------------------------------------------------------------------------------- map forms


def test_yaml_png_and_array_forms_read_alike(tmp_path: Path, half_known: HalfKnown) -> None:
    grid = half_known((-3.0, 2.0))
    occupied = grid.occupied.copy()
    occupied[25:28, 5:9] = True  # a block near the north-west corner: rows must not flip
    grid = OccupancyMap(grid.free & ~occupied, occupied, CELL, (-3.0, 2.0))
    save_occupancy_yaml(grid, tmp_path / "m.yaml")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.png", "m.yaml"]
    from_yaml = load_occupancy(tmp_path / "m.yaml")
    from_png = load_occupancy(tmp_path / "m.png", resolution=CELL, origin=(-3.0, 2.0))
    data = np.where(grid.occupied, 100, np.where(grid.free, 0, -1)).astype(np.int16)
    from_array = occupancy_from_array(data, CELL, (-3.0, 2.0, 0.0))
    for other in (from_yaml, from_png, from_array):
        assert np.array_equal(other.free, grid.free) and np.array_equal(other.occupied, grid.occupied)
        assert other.origin_xy == (-3.0, 2.0) and other.cell_m == CELL
    with Image.open(tmp_path / "m.png") as image:
        top = np.asarray(image)[2]  # image row 2 from the top = grid row 27 (north)
    assert (top[5:9] == 0).all()
    poses = [(-1.95, 3.55, 0.0)]
    results = [assign_goals(g, poses, "greedy") for g in (from_yaml, from_png, from_array)]
    assert results[0] == results[1] == results[2]
    assert assign_goals(str(tmp_path / "m.yaml"), poses, "greedy") == results[0]
    assert assign_goals(data, poses, "greedy", resolution=CELL, origin=(-3.0, 2.0)) == results[0]


def test_a_negated_yaml_reads_like_the_plain_one(tmp_path: Path, half_known: HalfKnown) -> None:
    save_occupancy_yaml(half_known(), tmp_path / "plain.yaml")
    doc = yaml.safe_load((tmp_path / "plain.yaml").read_text())
    with Image.open(tmp_path / "plain.png") as image:
        Image.fromarray(255 - np.asarray(image)).save(tmp_path / "negated.png")
    (tmp_path / "negated.yaml").write_text(yaml.safe_dump({**doc, "image": "negated.png", "negate": 1}))
    plain, negated = load_occupancy(tmp_path / "plain.yaml"), load_occupancy(tmp_path / "negated.yaml")
    assert np.array_equal(plain.free, negated.free) and np.array_equal(plain.occupied, negated.occupied)


def test_the_decision_on_a_saved_sim_map_is_the_simulators(
    tmp_path: Path, sarmis_played: tuple[AreaSearchEnv, dict[str, Any]]
) -> None:
    """A partial map written by the simulator's team, read back from its YAML, gives the candidates
    and distances that candidate extraction computes on the team's own map."""
    env, obs = sarmis_played
    world = env.world
    assert world.scene is not None and world.mapper is not None
    mapper, scene = world.mapper, world.scene
    save_occupancy_yaml(
        OccupancyMap(mapper.explored & ~mapper.occupied, mapper.occupied, scene.cell_m, scene.origin_xy),
        tmp_path / "m.yaml",
    )
    open_targets = np.flatnonzero(world.discovered & ~world.covered)
    decision = build_decision(load_occupancy(tmp_path / "m.yaml"), world.poses, world.targets_xy[open_targets])
    cells = scene.world_to_cell(world.poses[:, :2])
    assert np.array_equal(decision.robot_cells, cells)
    assert mapper.explored[cells[:, 0], cells[:, 1]].all()  # nothing to fill under the robots here
    expected = extract_candidates(
        mapper.explored,
        mapper.occupied,
        cells,
        world.target_cells[open_targets],
        np.arange(len(open_targets)),
        CandidateParams(cell_m=scene.cell_m, radius_m=world.config.robot.radius_m),
    ).limit(256)
    got = decision.candidates
    assert np.array_equal(got.cells, expected.cells) and np.array_equal(got.kind, expected.kind)
    assert np.array_equal(got.distance_m, expected.distance_m)
    # The observations, key by key. The simulator's candidates differ from the map's only by what
    # the simulator alone knows: frontiers near exhausted goals are dropped, bump marks are
    # impassable, failed goals are masked; there are none of those after these 3 decisions.
    assert env.planner is not None and not env.planner.bumps.any() and not env._exhausted
    assert len(env.candidates or ()) == len(expected)
    got_obs = decision.obs
    assert got_obs.keys() == obs.keys()
    same = ("candidates", "candidate_mask", "distances", "action_mask", "robots", "map_scale", "cell_m")
    for key in same:
        assert got_obs[key].dtype == obs[key].dtype and np.array_equal(got_obs[key], obs[key]), key
    # what differs: no past decisions were given, so no history and no history channels
    assert obs["history_mask"].tolist() == [1, 1, 1, 0, 0, 0, 0, 0]
    for key in ("history_robots", "history_goals", "history_mask"):
        assert got_obs[key].shape == obs[key].shape and not got_obs[key].any(), key
    assert got_obs["progress"][0] == 0.0 and obs["progress"][0] == world.metrics.steps / world.config.max_steps
    assert got_obs["map"].shape == obs["map"].shape
    for channel in (0, 2, 3, 4, 5):  # robots, frontiers, targets, obstacles, explored: the map's own channels
        assert np.array_equal(got_obs["map"][channel], obs["map"][channel]), channel
    # historical positions: the robots' cells alone, within the simulator's trajectory; no past goals
    assert np.array_equal(got_obs["map"][1], got_obs["map"][0])
    assert (obs["map"][1] >= got_obs["map"][1]).all() and obs["map"][1].sum() > got_obs["map"][1].sum()
    assert not got_obs["map"][6].any() and obs["map"][6].any()


def test_history_fills_the_observation(half_known: HalfKnown) -> None:
    grid = half_known()
    poses = [(1.05, 1.55, 0.0), (0.55, 0.55, 0.5)]
    past = [[(0.95, 1.55), (0.85, 1.55)], [(0.55, 0.45)]]
    goals = [[(2.95, 1.55), None], [None]]
    obs = build_decision(grid, poses, past_positions=past, past_goals=goals).obs
    assert obs["history_mask"].tolist() == [1, 1, 0, 0, 0, 0, 0, 0]
    assert obs["history_robots"][:2].tolist() == [[[15, 9], [4, 5]], [[15, 8], [-1, -1]]]
    assert obs["history_goals"][:2].tolist() == [[[15, 29], [-1, -1]], [[-1, -1], [-1, -1]]]
    assert obs["map"][6].sum() == 1  # one past goal cell
    with pytest.raises(ConfigError, match="one list per robot"):
        build_decision(grid, poses, past_positions=past[:1])


# ---------------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("poses", "message"),
    [
        ([(0.05, 1.55, 0.0)], "occupied cell"),
        ([(7.0, 1.0, 0.0)], "outside the map"),
        ([(1.0, -0.2, 0.0)], "outside the map"),
        ([(float("nan"), 1.0, 0.0)], "finite"),
        ([(1.0, 1.0, float("inf"))], "finite"),
        ([(1.0, 1.0, 0.0), (1.05, 1.0, 0.0)], "overlap"),
        ([], "at least one robot"),
        ([(1.0, 1.0)], "array of x, y, yaw"),
    ],
)
def test_bad_poses_are_refused(poses: list, message: str, half_known: HalfKnown) -> None:
    with pytest.raises(ConfigError, match=message):
        assign_goals(half_known(), poses)


def test_bad_maps_are_refused(half_known: HalfKnown) -> None:
    with pytest.raises(MapError, match="no free cell"):
        assign_goals(np.full((10, 10), 100, dtype=np.int8), [(0.5, 0.5, 0.0)], resolution=CELL)
    tiny = np.full((10, 10), 100, dtype=np.int8)
    tiny[4:6, 4:6] = 0
    with pytest.raises(MapError, match="smaller than the robots"):
        assign_goals(tiny, [(0.45, 0.45, 0.0)], resolution=CELL)
    with pytest.raises(MapError, match="values must be -1 or 0-100"):
        occupancy_from_array(np.full((5, 5), 101), CELL)
    with pytest.raises(MapError, match="resolution"):
        assign_goals(np.zeros((5, 5), dtype=np.int8), [(0.2, 0.2, 0.0)])
    with pytest.raises(ConfigError, match="unknown planner"):
        assign_goals(half_known(), [(1.0, 1.0, 0.0)], method="teleport")


# ---------------------------------------------------------------------------------- JSON and CLI


def test_json_files_are_read_and_checked(tmp_path: Path, examples: Path) -> None:
    robots = read_robots(examples / "robots.json")
    assert robots.ids == ["tb3_0", "tb3_1", "tb3_2"] and robots.poses.shape == (3, 3)
    ids, xy = read_targets(examples / "targets.json")
    assert len(ids) == len(xy) >= 1
    bad = tmp_path / "r.json"
    for doc, message in [
        ({"robots": [{"x": 1, "y": "2"}]}, r"robots\[0\].y must be a number"),
        ({"robots": [{"x": 1}]}, "has no 'y'"),
        ({"robots": [{"x": 1, "y": 1, "speed": 2}]}, "unknown field"),
        ({"robots": [{"id": "a", "x": 1, "y": 1}, {"id": "a", "x": 2, "y": 1}]}, "used twice"),
        ({"robots": []}, "empty"),
        ([1, 2], "'robots' list"),
    ]:
        bad.write_text(json.dumps(doc))
        with pytest.raises(ConfigError, match=message):
            read_robots(bad)
    bad.write_text('{"robots": [{"x": NaN, "y": 1}]}')
    with pytest.raises(ConfigError, match="finite"):
        read_robots(bad)


def test_cli_assign_prints_the_library_result(tmp_path: Path, examples: Path, run_cli: CliRunner) -> None:
    args = ["--map", str(examples / "partial_map.yaml"), "--robots", str(examples / "robots.json")]
    args += ["--targets", str(examples / "targets.json"), "--method", "utility", "--seed", "2"]
    out = tmp_path / "goals.json"
    result = run_cli("assign", *args, "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert result.stdout == "" and sorted(p.name for p in tmp_path.iterdir()) == ["goals.json"]
    doc = json.loads(out.read_text())
    robots = read_robots(examples / "robots.json")
    target_ids, targets = read_targets(examples / "targets.json")
    expected = assign_goals(
        examples / "partial_map.yaml",
        robots.poses,
        "utility",
        targets,
        robots.past_positions,
        robots.past_goals,
        seed=2,
    )
    assert doc["frame"] == "map" and doc["method"] == "utility"
    assert [r["id"] for r in doc["robots"]] == robots.ids
    for entry, a in zip(doc["robots"], expected, strict=True):
        assert entry["type"] == a.kind
        assert entry["goal"] == pytest.approx(a.goal_xy, abs=1e-4)
        assert entry["target"] == (None if a.target is None else target_ids[a.target])
        assert np.allclose(entry["path"], a.path_xy, atol=1e-4)
