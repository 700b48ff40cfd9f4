"""The ROS 2 node's pure parts, without ROS: messages read as the goal call's inputs (:mod:`areasearch.ros2.convert`),
bad messages named by their cause and logged once (:mod:`areasearch.ros2.checks`), the parameters checked
(:mod:`areasearch.ros2.settings`). Messages are stand-ins with the messages' fields."""

from __future__ import annotations

import array
import math
from types import SimpleNamespace as NS
from typing import Any

import numpy as np
import pytest

from areasearch.errors import ConfigError, MapError
from areasearch.ros2.checks import Problem, Problems, pose_problem, read_map, targets_problem, usable_targets
from areasearch.ros2.convert import (
    RobotPose,
    candidate_points,
    grid_from_message,
    pose_from_message,
    quaternion_xyzw,
    targets_from_message,
    yaw_of,
)
from areasearch.ros2.settings import NodeSettings, node_settings
from areasearch.service.answer import Assignment
from areasearch.service.assign import build_decision, occupancy_from_array


def grid_msg(cells: np.ndarray, resolution: float = 0.1, origin: tuple[float, float] = (0.0, 0.0), **q: float) -> Any:
    """An OccupancyGrid stand-in: ``cells`` (H, W) row 0 at the origin, data as rclpy gives it (array 'b')."""
    h, w = cells.shape if cells.ndim == 2 else (0, 0)
    quaternion = NS(**{"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0, **q})
    info = NS(width=w, height=h, resolution=np.float32(resolution),
              origin=NS(position=NS(x=origin[0], y=origin[1], z=0.0), orientation=quaternion))  # fmt: skip
    return NS(header=NS(frame_id="map"), info=info, data=array.array("b", cells.astype(np.int8).tobytes()))


def room() -> np.ndarray:
    """A 6 x 3 m room of 0.1 m cells, walled, its western half known free, the rest unknown."""
    cells = np.full((30, 60), -1, dtype=np.int8)
    cells[:, :30] = 0
    cells[[0, -1], :] = 100
    cells[:, [0, -1]] = 100
    return cells


def pose_msg(x: float, y: float, yaw: float, frame: str = "map") -> Any:
    qx, qy, qz, qw = quaternion_xyzw(yaw)
    pose = NS(position=NS(x=x, y=y, z=0.0), orientation=NS(x=qx, y=qy, z=qz, w=qw))
    return NS(header=NS(frame_id=frame), pose=NS(pose=pose))


# ---------------------------------------------------------------------------------- convert


def test_a_grid_message_reads_as_the_array_reader_reads_it() -> None:
    cells = room()
    cells[5, 7] = 50  # between the thresholds: unknown
    grid = grid_from_message(grid_msg(cells, 0.05, (-4.0, -6.5)))
    same = occupancy_from_array(cells, 0.05, (-4.0, -6.5))
    assert (grid.free == same.free).all() and (grid.occupied == same.occupied).all()
    assert grid.cell_m == 0.05  # the float32 of the message read back as the YAML's 0.05
    assert grid.origin_xy == (-4.0, -6.5)
    assert grid.cell_to_world(np.array([0, 0])).tolist() == [-3.975, -6.475]


def test_row_zero_of_the_data_is_at_the_origin() -> None:
    cells = room()
    cells[1, 1] = 100  # one cell by the south-west corner
    grid = grid_from_message(grid_msg(cells, 0.1, (2.0, 3.0)))
    iy, ix = grid.world_to_cell(np.array([2.15, 3.15]))
    assert (iy, ix) == (1, 1) and grid.occupied[iy, ix]


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"z": math.sin(0.25), "w": math.cos(0.25)}, "rotated maps are not supported"),
        ({"x": 0.3, "w": 0.95}, "tilted"),
        ({"w": math.nan}, "quaternion of finite numbers"),
    ],
)
def test_a_rotated_tilted_or_broken_origin_is_refused(change: dict[str, float], words: str) -> None:
    with pytest.raises(MapError, match=words):
        grid_from_message(grid_msg(room(), **change))


def test_an_all_zero_origin_quaternion_is_read_as_unset() -> None:
    assert grid_from_message(grid_msg(room(), x=0.0, y=0.0, z=0.0, w=0.0)).shape == (30, 60)


def test_poses_read_from_amcl_and_odometry_fields() -> None:
    pose = pose_from_message(pose_msg(1.5, -2.0, 2.5, frame="/map"))
    assert pose.frame == "map"  # a leading slash (ROS 1) dropped, as tf2 does
    assert (pose.x, pose.y) == (1.5, -2.0) and pose.yaw == pytest.approx(2.5)
    assert yaw_of(NS(x=0.0, y=0.0, z=0.0, w=0.0)) != yaw_of(NS(x=0.0, y=0.0, z=0.0, w=0.0))  # NaN
    assert yaw_of(NS(x=0.0, y=0.0, z=2.0, w=0.0)) == pytest.approx(math.pi)  # any norm


def test_targets_read_from_a_pose_array() -> None:
    msg = NS(header=NS(frame_id="map"), poses=[pose_msg(1.0, 2.0, 0.0).pose.pose, pose_msg(3.0, 4.0, 0.0).pose.pose])
    xy, frame = targets_from_message(msg)
    assert xy.tolist() == [[1.0, 2.0], [3.0, 4.0]] and frame == "map"
    empty, _ = targets_from_message(NS(header=NS(frame_id="map"), poses=[]))
    assert empty.shape == (0, 2)


def test_candidate_points_are_the_decision_candidates_in_metres() -> None:
    grid = occupancy_from_array(room(), 0.1)
    decision = build_decision(grid, [(1.05, 1.55, 0.0)], targets=[(2.0, 1.5)])
    frontiers, targets = candidate_points(decision.obs, grid)
    cand = decision.candidates
    assert len(frontiers) + len(targets) == len(cand)
    assert targets.tolist() == [grid.cell_to_world(cand.cells[cand.kind == 1][0]).tolist()]
    assert np.allclose(frontiers[:, 0], 2.95)  # the one straight frontier at ix = 29


def test_goal_heading_follows_the_last_path_step() -> None:
    from areasearch.ros2.convert import goal_yaw

    a = Assignment(0, "frontier", (1.0, 1.0), None, 1.0, [(0.0, 1.0), (0.5, 1.0), (1.0, 1.5)])
    assert goal_yaw(a, 0.3) == pytest.approx(math.pi / 4)
    assert goal_yaw(Assignment(0, "frontier", (1.0, 1.0), None, 0.0, [(1.0, 1.0)]), 0.3) == 0.3


# ---------------------------------------------------------------------------------- checks


@pytest.mark.parametrize(
    ("cells", "cause"),
    [
        (np.zeros((0, 0), dtype=np.int8), "empty map"),
        (np.full((20, 20), -1, dtype=np.int8), "all-unknown map"),
        (np.full((20, 20), 100, dtype=np.int8), "unusable map: the map has no free cell"),
    ],
)
def test_unusable_maps_are_named_by_their_cause(cells: np.ndarray, cause: str) -> None:
    problem = read_map(grid_msg(cells))
    assert isinstance(problem, Problem) and problem.cause == cause and problem.subject == "/map"


def test_a_map_whose_size_does_not_match_its_data_is_unusable() -> None:
    msg = grid_msg(room())
    msg.info.width = 61
    problem = read_map(msg)
    assert isinstance(problem, Problem) and problem.cause.startswith("unusable map") and "61" in problem.message


def test_bad_poses_are_named_by_their_cause() -> None:
    grid = occupancy_from_array(room(), 0.1)
    good = RobotPose(1.05, 1.55, 0.0, "map")
    assert pose_problem(good, "r1", grid, "map") is None
    cases = {
        "pose not finite": good._replace(x=math.nan),
        "frame": good._replace(frame="odom"),
        "off the map": good._replace(x=100.0),
        "in a wall": good._replace(x=0.05),
    }
    for cause, pose in cases.items():
        problem = pose_problem(pose, "r1", grid, "map")
        assert problem is not None and problem.cause == cause and problem.subject == "r1", (cause, problem)
    assert pose_problem(good._replace(yaw=math.nan), "r1") is not None  # without a map: finiteness only


def test_targets_off_the_map_or_in_another_frame_are_left_out() -> None:
    grid = occupancy_from_array(room(), 0.1)
    xy = np.array([[1.0, 1.0], [50.0, 1.0], [2.0, 2.0]])
    kept, ids, problems = usable_targets(xy, "map", grid, "map")
    assert kept.tolist() == [[1.0, 1.0], [2.0, 2.0]] and ids == [0, 2]
    assert [p.cause for p in problems] == ["target off the map"]
    kept, ids, problems = usable_targets(xy, "odom", grid, "map")
    assert len(kept) == 0 and [p.cause for p in problems] == ["frame"]
    assert targets_problem(np.array([[1.0, math.nan]])) is not None and targets_problem(xy) is None


def test_each_cause_is_logged_once_and_counted_each_time() -> None:
    lines: list[str] = []
    problems = Problems(lines.append)
    nan = Problem("pose not finite", "r1", "pose (nan, 0, yaw 0) is not finite")
    for _ in range(3):
        problems.report(nan, "left out")
    problems.report(Problem("pose not finite", "r2", "pose (nan, 1, yaw 0) is not finite"), "left out")
    problems.report(Problem("in a wall", "r1", "in a wall"), "left out")
    assert lines == [
        "r1: pose (nan, 0, yaw 0) is not finite; left out (logged once)",
        "r2: pose (nan, 1, yaw 0) is not finite; left out (logged once)",
        "r1: in a wall; left out (logged once)",
    ]
    assert problems.counts[("pose not finite", "r1")] == 3


# ---------------------------------------------------------------------------------- settings


def test_settings_from_parameters() -> None:
    settings = node_settings({"robots": ["/r1", "fleet/r2/"], "period_s": 2, "method": "voronoi", "seed": 3})
    assert settings == NodeSettings(robots=("r1", "fleet/r2"), period_s=2.0, method="voronoi", seed=3)
    assert settings.config.world.robot.radius_m == 0.18


@pytest.mark.parametrize(
    ("values", "words"),
    [
        ({}, "no robots"),
        ({"robots": []}, "no robots"),
        ({"robots": "r1"}, "must be a list of namespaces"),
        ({"robots": ["1r"]}, "is not a ROS namespace"),
        ({"robots": ["r1", "r1"]}, "r1 given twice"),
        ({"robots": [f"r{k}" for k in range(9)]}, "at most 8"),
        ({"robots": ["r1"], "pose_source": "tf"}, "pose_source must be one of amcl, odom"),
        ({"robots": ["r1"], "period_s": 0.0}, r"period_s must be a number in \[0.05, 86400\]"),
        ({"robots": ["r1"], "period_s": math.inf}, "period_s"),
        ({"robots": ["r1"], "period_s": True}, "period_s"),
        ({"robots": ["r1"], "goal_tolerance_m": 0.0}, "goal_tolerance_m"),
        ({"robots": ["r1"], "radius_m": 1e9}, "radius_m"),
        ({"robots": ["r1"], "seed": -1}, "seed must be a non-negative integer"),
        ({"robots": ["r1"], "method": 3}, "method must be a string"),
        ({"robots": ["r1"], "speed": 3}, "unknown parameter"),
    ],
)
def test_bad_parameters_are_refused_naming_them(values: dict[str, Any], words: str) -> None:
    with pytest.raises(ConfigError, match=words):
        node_settings(values)
