"""The ROS 2 node with real rclpy (the ``ros2`` extra; skipped, saying so, without it): a test team
publishes a map as map_server does and poses as AMCL does, and receives the node's goals.

Every test runs in its own ROS domain (``ROS_DOMAIN_ID`` from this process's id, discovery kept
on this machine), so parallel runs do not hear each other. The map is the partial map of
``examples/`` (what three robots mapped of a flat) with its three robots: the goals must be
``assign_goals``'s on the same input.
"""

from __future__ import annotations

import array
import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

WHY = "the ros2 extra is not installed (pip install 'areasearch[ros2]'): {} is missing"
rclpy = pytest.importorskip("rclpy", reason=WHY.format("rclpy"))
for _module in ("geometry_msgs.msg", "nav_msgs.msg", "std_msgs.msg", "visualization_msgs.msg"):
    pytest.importorskip(_module, reason=WHY.format(_module.split(".")[0]))

from geometry_msgs.msg import PoseArray, PoseStamped, PoseWithCovarianceStamped  # noqa: E402
from nav_msgs.msg import OccupancyGrid  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.signals import SignalHandlerOptions  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

from areasearch.planners import shipped_policy  # noqa: E402
from areasearch.planning.frontiers import frontier_mask  # noqa: E402
from areasearch.ros2.convert import quaternion_xyzw, yaw_of  # noqa: E402
from areasearch.ros2.node import LATCHED, RELIABLE, AreaSearchNode  # noqa: E402
from areasearch.service.assign import (  # noqa: E402
    OccupancyMap,
    RobotsFile,
    assign_goals,
    assignments_json,
    dumps,
    load_occupancy,
    read_robots,
    read_targets,
)

DOMAIN = str(1 + os.getpid() % 100)
"""This run's ROS domain (1-100)."""
WAIT_S = 20.0
"""Longest wait for a message (a loaded machine; normally well under a second)."""


@pytest.fixture(scope="module")
def context() -> Iterator[Context]:
    """An rclpy context in this run's own domain."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("ROS_DOMAIN_ID", DOMAIN)
        mp.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        ctx = Context()
        rclpy.init(args=[], context=ctx, signal_handler_options=SignalHandlerOptions.NO)
        yield ctx
        ctx.try_shutdown()


@pytest.fixture(scope="module")
def flat(examples: Path) -> tuple[OccupancyMap, RobotsFile]:
    """The examples' partial map and its three robots."""
    return load_occupancy(examples / "partial_map.yaml"), read_robots(examples / "robots.json")


def map_message(grid: OccupancyMap, frame: str = "map", cells: np.ndarray | None = None) -> OccupancyGrid:
    """``grid`` as map_server publishes it (0 free, 100 occupied, -1 unknown), or ``cells`` on its frame."""
    if cells is None:
        cells = np.full(grid.shape, -1, dtype=np.int8)
        cells[grid.free] = 0
        cells[grid.occupied] = 100
    msg = OccupancyGrid()
    msg.header.frame_id = frame
    msg.info.height, msg.info.width = (int(v) for v in cells.shape) if cells.size else (0, 0)
    msg.info.resolution = grid.cell_m
    msg.info.origin.position.x, msg.info.origin.position.y = grid.origin_xy
    msg.info.origin.orientation.w = 1.0
    msg.data = array.array("b", cells.astype(np.int8).tobytes())
    return msg


def pose_message(x: float, y: float, yaw: float, frame: str = "map") -> PoseWithCovarianceStamped:
    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = frame
    msg.pose.pose.position.x, msg.pose.pose.position.y = float(x), float(y)
    q = msg.pose.pose.orientation
    q.x, q.y, q.z, q.w = quaternion_xyzw(float(yaw))
    return msg


@dataclass
class Team:
    """The test's side: publishers of the map, the robots' poses and targets; what the node sent back."""

    node: Any
    names: list[str]
    goals: dict[str, list[PoseStamped]] = field(default_factory=dict)
    status: list[str] = field(default_factory=list)
    markers: list[MarkerArray] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.map_publisher = self.node.create_publisher(OccupancyGrid, "/map", LATCHED)
        self.pose_publishers = {
            n: self.node.create_publisher(PoseWithCovarianceStamped, f"/{n}/amcl_pose", LATCHED) for n in self.names
        }
        self.targets_publisher = self.node.create_publisher(PoseArray, "/areasearch/targets", RELIABLE)
        for n in self.names:
            self.goals[n] = []
            self.node.create_subscription(PoseStamped, f"/{n}/goal_pose", self.goals[n].append, RELIABLE)
        self.node.create_subscription(String, "/areasearch/status", lambda m: self.status.append(m.data), LATCHED)
        self.node.create_subscription(MarkerArray, "/areasearch/markers", self.markers.append, LATCHED)

    def poses(self, poses: np.ndarray, frame: str = "map") -> None:
        for n, (x, y, yaw) in zip(self.names, poses, strict=True):
            self.pose_publishers[n].publish(pose_message(x, y, yaw, frame))

    def goal_xy(self, name: str, k: int = -1) -> tuple[float, float]:
        p = self.goals[name][k].pose.position
        return (p.x, p.y)


@dataclass
class Run:
    """The node under test and the team, spun by one executor in the test's thread."""

    node: AreaSearchNode
    team: Team
    executor: SingleThreadedExecutor

    def spin_until(self, done: Callable[[], bool], timeout: float = WAIT_S) -> float:
        """Spin until ``done()``; the seconds it took (fails after ``timeout``)."""
        started = time.perf_counter()
        while not done():
            assert time.perf_counter() - started < timeout, (
                f"nothing after {timeout:g} s; node: {self.node.problems.logged}"
            )
            self.executor.spin_once(timeout_sec=0.02)
        return time.perf_counter() - started

    def spin_for(self, seconds: float) -> None:
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            self.executor.spin_once(timeout_sec=0.02)


@pytest.fixture
def start(context: Context) -> Iterator[Callable[..., Run]]:
    """``start(names, **given)``: the node with the options ``given`` and a team of ``names``."""
    made: list[tuple[SingleThreadedExecutor, list[Any]]] = []

    def make(names: list[str], **given: Any) -> Run:
        node = AreaSearchNode({"robots": names, **given}, context=context)
        team = Team(Node("areasearch_test_team", context=context), names)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        executor.add_node(team.node)
        made.append((executor, [node, team.node]))
        return Run(node, team, executor)

    yield make
    for executor, nodes in made:
        executor.shutdown()
        for node in nodes:
            node.destroy_node()


def first_goals(run: Run, grid: OccupancyMap, poses: np.ndarray) -> float:
    """Publish the map and the poses; the seconds until every robot has a goal."""
    run.team.map_publisher.publish(map_message(grid))
    run.team.poses(poses)
    return run.spin_until(lambda: all(run.team.goals.values()))


# ---------------------------------------------------------------------------------- goals


def test_one_goal_per_robot_equal_to_assign_goals(start: Callable[..., Run], flat: Any) -> None:
    grid, robots = flat
    run = start(robots.ids, period_s=3600.0)
    seconds = first_goals(run, grid, robots.poses)
    assert seconds < WAIT_S
    expected = assign_goals(grid, robots.poses, "greedy")
    goals = [run.team.goal_xy(n) for n in robots.ids]
    assert goals == [a.goal_xy for a in expected]  # the same numbers, to the last bit
    assert len(set(goals)) == len(goals)  # one robot per goal
    frontier = np.argwhere(frontier_mask(grid.explored, grid.occupied))
    for a in expected:  # a free cell; a frontier node: within the snap distance (0.5 m) of the frontier
        cell = grid.world_to_cell(np.array(a.goal_xy))
        assert grid.free[cell[0], cell[1]], a
        assert a.kind == "frontier" and np.hypot(*(frontier - cell).T).min() * grid.cell_m <= 0.5, a
    for n, a in zip(robots.ids, expected, strict=True):
        msg = run.team.goals[n][-1]
        assert msg.header.frame_id == "map" and len(run.team.goals[n]) == 1
        (x0, y0), (x1, y1) = a.path_xy[-2], a.path_xy[-1]
        assert yaw_of(msg.pose.orientation) == pytest.approx(math.atan2(y1 - y0, x1 - x0))  # along the last step
    run.spin_until(lambda: bool(run.team.status) and bool(run.team.markers))
    assert run.team.status[-1] == dumps(assignments_json(expected, robots.ids, [], "greedy"))
    spaces = [m.ns for m in run.team.markers[-1].markers if m.action == Marker.ADD]
    assert spaces.count("goals") == spaces.count("paths") == 3 and "frontiers" in spaces
    assert run.node.problems.logged == []


def test_a_robot_reaching_its_goal_gets_the_next_one_at_once(start: Callable[..., Run], flat: Any) -> None:
    grid, robots = flat
    run = start(robots.ids, period_s=3600.0)
    first_goals(run, grid, robots.poses)
    first = [run.team.goal_xy(n) for n in robots.ids]
    moved = robots.poses.copy()
    moved[1, :2] += 0.1  # moving, not there yet: no decision
    run.team.poses(moved)
    run.spin_for(1.0)
    assert [len(run.team.goals[n]) for n in robots.ids] == [1, 1, 1]
    moved[0, :2] = first[0]  # tb3_0 arrives
    run.team.poses(moved)
    seconds = run.spin_until(lambda: all(len(run.team.goals[n]) == 2 for n in robots.ids))
    assert seconds < WAIT_S
    expected = assign_goals(
        grid,
        moved,
        "greedy",
        past_positions=[[tuple(p[:2])] for p in robots.poses],
        past_goals=[[g] for g in first],
    )
    assert [run.team.goal_xy(n) for n in robots.ids] == [a.goal_xy for a in expected]
    assert run.team.goal_xy("tb3_0") != first[0]


def test_known_targets_are_goals(start: Callable[..., Run], flat: Any, examples: Path) -> None:
    grid, robots = flat
    target_ids, targets = read_targets(examples / "targets.json")
    run = start(robots.ids, period_s=3600.0, method="voronoi")
    msg = PoseArray()
    msg.header.frame_id = "map"
    msg.poses = [pose_message(x, y, 0.0).pose.pose for x, y in targets]
    run.spin_until(lambda: run.team.targets_publisher.get_subscription_count() > 0)
    run.team.targets_publisher.publish(msg)
    run.spin_until(lambda: len(run.node.targets_xy) == len(targets))
    first_goals(run, grid, robots.poses)
    expected = assign_goals(grid, robots.poses, "voronoi", targets)
    assert "target" in [a.kind for a in expected]
    assert [run.team.goal_xy(n) for n in robots.ids] == [a.goal_xy for a in expected]
    run.spin_until(lambda: bool(run.team.status))
    ids = [f"target_{t}" for t in range(len(target_ids))]  # named by their index in the PoseArray
    assert run.team.status[-1] == dumps(assignments_json(expected, robots.ids, ids, "voronoi"))


# ---------------------------------------------------------------------------------- bad messages


def _wall(grid: OccupancyMap) -> tuple[float, float]:
    iy, ix = np.argwhere(grid.occupied)[len(np.argwhere(grid.occupied)) // 2]
    x, y = grid.cell_to_world(np.array([iy, ix]))
    return float(x), float(y)


BAD = {
    # case: (what is published instead of the good map / poses, the (cause, subject) met, robots without goals)
    "empty map": ("map", ("empty map", "/map"), ["tb3_0", "tb3_1", "tb3_2"]),
    "all-unknown map": ("map", ("all-unknown map", "/map"), ["tb3_0", "tb3_1", "tb3_2"]),
    "NaN pose": ("pose", ("pose not finite", "tb3_1"), ["tb3_1"]),
    "robot off the map": ("pose", ("off the map", "tb3_1"), ["tb3_1"]),
    "robot in a wall": ("pose", ("in a wall", "tb3_1"), ["tb3_1"]),
    "map frame differs from the poses'": ("pose", ("frame", "tb3_0"), ["tb3_0", "tb3_1", "tb3_2"]),
}


def _publish_bad(run: Run, case: str, grid: OccupancyMap, poses: np.ndarray) -> None:
    team = run.team
    if case == "empty map":
        team.map_publisher.publish(map_message(grid, cells=np.zeros((0, 0), dtype=np.int8)))
    elif case == "all-unknown map":
        team.map_publisher.publish(map_message(grid, cells=np.full(grid.shape, -1, dtype=np.int8)))
    elif case == "map frame differs from the poses'":
        team.poses(poses, frame="odom")
    else:
        bad = poses.copy()
        bad[1] = {"NaN pose": (math.nan, 0.0, 0.0), "robot off the map": (100.0, 100.0, 0.0)}.get(
            case, (*_wall(grid), 0.0)
        )
        team.poses(bad)


@pytest.mark.parametrize("case", list(BAD))
def test_a_bad_message_is_logged_once_never_planned_on_and_survived(
    case: str, start: Callable[..., Run], flat: Any
) -> None:
    grid, robots = flat
    what, key, silent = BAD[case]
    run = start(robots.ids, period_s=0.3)
    if what == "pose":
        run.team.map_publisher.publish(map_message(grid))
    else:
        run.team.poses(robots.poses)
    for _ in range(3):  # the bad message, again and again; decisions every 0.3 s meanwhile
        _publish_bad(run, case, grid, robots.poses)
        run.spin_for(0.5)
    run.spin_until(lambda: run.node.problems.counts[key] >= 3)
    warned = [line for line in run.node.problems.logged if line.endswith("(logged once)")]
    assert sum(line.startswith(f"{key[1]}: ") for line in warned) == 1, warned
    assert all(not run.team.goals[n] for n in silent), "a goal from bad data"
    for n in set(robots.ids) - set(silent):
        assert run.team.goals[n], f"{n} got no goal beside a bad message of another robot"
    # good messages again: the node plans for every robot
    run.team.map_publisher.publish(map_message(grid))
    run.team.poses(robots.poses)
    assert run.spin_until(lambda: all(run.team.goals[n] for n in robots.ids)) < WAIT_S
    subjects = {key[1], *silent}
    warned = [line for line in run.node.problems.logged if line.endswith("(logged once)")]
    left = [line for line in warned if line.split(":")[0] not in subjects]
    assert left == [], left


def test_bad_targets_are_ignored(start: Callable[..., Run], flat: Any) -> None:
    grid, robots = flat
    run = start(robots.ids, period_s=0.3)
    msg = PoseArray()
    msg.header.frame_id = "map"
    msg.poses.append(pose_message(math.nan, 0.0, 0.0).pose.pose)
    run.team.targets_publisher.publish(msg)
    first_goals(run, grid, robots.poses)
    run.spin_until(lambda: run.node.problems.counts[("targets not finite", "/areasearch/targets")] == 1)
    assert all(a.kind == "frontier" for a in run.node.last_answer or [])


class _Broken:
    name = "broken"

    def reset(self, rng: np.random.Generator) -> None:
        pass

    def assign(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        raise RuntimeError("a plug-in's bug")


def test_a_planner_that_raises_leaves_the_node_running(start: Callable[..., Run], flat: Any) -> None:
    grid, robots = flat
    run = start(robots.ids, period_s=0.3)
    planner, run.node.planner.planner = run.node.planner.planner, _Broken()
    run.team.map_publisher.publish(map_message(grid))
    run.team.poses(robots.poses)
    run.spin_until(lambda: run.node.problems.counts[("failed: RuntimeError", "decision")] >= 3)
    assert not any(run.team.goals.values())
    assert run.node.problems.logged == [
        "decision: the planner failed: RuntimeError: a plug-in's bug; no goal is published from this decision "
        "(logged once)"
    ]
    run.node.planner.planner = planner
    run.spin_until(lambda: all(run.team.goals.values()))


# ---------------------------------------------------------------------------------- learned, CLI


@pytest.mark.slow
@pytest.mark.parametrize("given", [{"method": "dahgnn"}, {"weights": str(shipped_policy("dahgnn"))}], ids=str)
def test_a_learned_planner_gives_assign_goals_answer(
    given: dict[str, str], start: Callable[..., Run], flat: Any
) -> None:
    grid, robots = flat
    run = start(robots.ids, period_s=3600.0, **given)
    first_goals(run, grid, robots.poses)
    expected = assign_goals(grid, robots.poses, "dahgnn")
    assert [run.team.goal_xy(n) for n in robots.ids] == [a.goal_xy for a in expected]
    run.spin_until(lambda: bool(run.team.status))
    status = json.loads(run.team.status[-1])
    assert status["method"] == "dahgnn" and ("weights_sha256" in status) == ("weights" in given)


@pytest.mark.slow
def test_the_command_runs_the_node_until_ctrl_c(context: Context, flat: Any, root: Path) -> None:
    grid, robots = flat
    env = {**os.environ, "ROS_DOMAIN_ID": DOMAIN, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "PYTHONUNBUFFERED": "1"}
    command = [sys.executable, "-m", "areasearch.cli", "ros2", "--robots", *robots.ids, "--period-s", "3600"]
    command += ["--ros-args", "-r", "/map:=/test_map", "-p", "goal_tolerance_m:=0.3", "--log-level", "info"]
    proc = subprocess.Popen(command, cwd=root, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    team = Team(Node("areasearch_test_cli", context=context), robots.ids)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(team.node)
    try:
        latched = team.node.create_publisher(OccupancyGrid, "/test_map", LATCHED)
        started = time.perf_counter()
        # goals are not latched: the node's publishers must be matched before it decides
        while any(team.node.count_publishers(f"/{n}/goal_pose") == 0 for n in robots.ids):
            assert proc.poll() is None, proc.communicate()
            assert time.perf_counter() - started < 120, "the command did not start"
            executor.spin_once(timeout_sec=0.05)
        end = time.perf_counter() + 0.5
        while time.perf_counter() < end:
            executor.spin_once(timeout_sec=0.05)
        latched.publish(map_message(grid))
        team.poses(robots.poses)
        started = time.perf_counter()
        while not all(team.goals.values()):
            assert proc.poll() is None, proc.communicate()
            assert time.perf_counter() - started < 120, "no goals from the command"
            executor.spin_once(timeout_sec=0.05)
        assert [(g[-1].pose.position.x, g[-1].pose.position.y) for g in team.goals.values()] == [
            a.goal_xy for a in assign_goals(grid, robots.poses, "greedy")
        ]
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
        executor.shutdown()
        team.node.destroy_node()
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    assert "ready: greedy for tb3_0, tb3_1, tb3_2" in err and "within 0.3 m of its goal" in err  # -p applied


def test_the_parameters_file_example_sets_the_node(examples: Path) -> None:
    ctx = Context()
    args = ["--ros-args", "--params-file", str(examples / "ros2" / "areasearch.yaml"), "-p", "method:=greedy"]
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("ROS_DOMAIN_ID", DOMAIN)
        rclpy.init(args=args, context=ctx, signal_handler_options=SignalHandlerOptions.NO)
        try:
            node = AreaSearchNode(context=ctx)  # the file's values (the method, which loads PyTorch, replaced)
            assert node.settings.robots == ("tb3_0", "tb3_1", "tb3_2") and node.settings.period_s == 5.0
            assert node.choice.method == "greedy" and node.settings.goal_tolerance_m == 0.25
            node.destroy_node()
        finally:
            ctx.try_shutdown()
    source = (examples / "ros2" / "areasearch.launch.py").read_text()
    compile(source, "areasearch.launch.py", "exec")  # a valid launch file (ros2 launch is not installed here)
    assert 'arguments=["ros2"]' in source and "areasearch.yaml" in source
