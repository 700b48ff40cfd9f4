"""The ROS 2 node of ``areasearch ros2``: one node plans the goals of a whole team (:class:`AreaSearchNode`).

Topics (``<ns>``: each robot's namespace, parameter ``robots``):

============================ ================================= ==========================================
topic                        type                              QoS
============================ ================================= ==========================================
in ``/map``                  nav_msgs/OccupancyGrid            reliable, transient local (map_server, slam_toolbox)
in ``/<ns>/amcl_pose``       geometry_msgs/PoseWithCovarianceStamped  reliable, transient local (Nav2's AMCL)
in ``/<ns>/odom``            nav_msgs/Odometry                 best effort (matches any publisher)
in ``/areasearch/targets``   geometry_msgs/PoseArray           reliable
out ``/<ns>/goal_pose``      geometry_msgs/PoseStamped         reliable (Nav2's bt_navigator listens)
out ``/areasearch/markers``  visualization_msgs/MarkerArray    reliable, transient local
out ``/areasearch/status``   std_msgs/String                   reliable, transient local
============================ ================================= ==========================================

When it decides: as soon as the map and a first pose of every robot are in; then every
``period_s`` seconds (the node's clock: simulated time under ``use_sim_time``); and at once when a
robot comes within ``goal_tolerance_m`` of its goal (a goal given within the tolerance of the
robot counts once the robot has been more than twice the tolerance away from it: never a decision
on every pose message of a robot standing at its goal). A decision is one
:func:`areasearch.service.assign.assign_goals` call on the last good map with the robots whose
last pose is good, the known targets on the map, and each robot's positions and goals at its past
decisions (the learned planners read them); it publishes each robot's goal (heading along the
last step of its path), the markers of the decision (:mod:`.messages`) and the JSON answer of
``areasearch assign`` (:func:`areasearch.service.answer.assignments_json`, robots named by
namespace, targets ``target_<i>`` by their index in the PoseArray). A robot with no reachable
goal gets none (``"type": "none"`` in the answer). Bad messages are never planned on and never
stop the node (:mod:`.checks`).

Callbacks run one at a time (one executor thread), so a decision sees one consistent state.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
import rclpy
from geometry_msgs.msg import PoseArray, PoseStamped, PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

from ..errors import AreaSearchError, ConfigError
from ..planners import GoalPlanner, choose_planner
from ..service.assign import Assignments, assign_goals, assignments_json, dumps, occupancy_from_array
from ..service.grid import OccupancyMap
from .checks import (
    LEFT_OUT,
    MAP_UNUSED,
    NO_GOALS,
    TARGET_LEFT_OUT,
    TARGETS,
    TARGETS_IGNORED,
    Problem,
    Problems,
    pose_problem,
    read_map,
    refused,
    targets_problem,
    usable_targets,
)
from .convert import RobotPose, candidate_points, frame_id, goal_yaw, pose_from_message, targets_from_message
from .messages import goal_message, marker_array, status_message
from .settings import PARAMETERS, NodeSettings, default_values, node_settings

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""map_server's and slam_toolbox's ``/map``, AMCL's ``amcl_pose``: a late subscriber gets the last message."""
STREAM = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
"""Odometry: best effort takes both reliable and best-effort publishers."""
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
"""Goals (Nav2's ``goal_pose`` subscription is reliable, volatile) and targets."""

MAP_TOPIC = "/map"
MARKERS_TOPIC = "/areasearch/markers"
STATUS_TOPIC = "/areasearch/status"


def pose_topic(namespace: str, source: str) -> str:
    """The topic of a robot's pose: ``/<ns>/amcl_pose`` or ``/<ns>/odom``."""
    return f"/{namespace}/{'amcl_pose' if source == 'amcl' else 'odom'}"


def goal_topic(namespace: str) -> str:
    return f"/{namespace}/goal_pose"


@dataclass
class _Robot:
    """What the node knows of one robot."""

    name: str
    """Its namespace."""
    history: int
    """How many past decisions to keep (``decisions.history``)."""
    pose: RobotPose | None = None
    """Its last pose, None before the first or after a bad one."""
    heard: bool = False
    """A pose message has come (good or bad)."""
    goal: tuple[float, float] | None = None
    """Its current goal, map frame."""
    armed: bool = False
    """Coming within the tolerance of :attr:`goal` triggers a decision: set when the goal is given farther
    than the tolerance from the robot, or once the robot is more than twice the tolerance from it;
    cleared when it triggers (once per arrival, never again and again while the robot stands there)."""
    past_positions: deque[tuple[float, float]] = field(init=False)
    past_goals: deque[tuple[float, float] | None] = field(init=False)

    def __post_init__(self) -> None:
        self.past_positions = deque(maxlen=self.history)
        self.past_goals = deque(maxlen=self.history)


class _Watched:
    """The planner, keeping the observation of its last call: the markers draw the candidates the
    planner chose among, without building the decision twice."""

    def __init__(self, planner: GoalPlanner) -> None:
        self.planner = planner
        self.name = getattr(planner, "name", "planner")
        self.obs: dict[str, np.ndarray] | None = None

    def reset(self, rng: np.random.Generator) -> None:
        self.planner.reset(rng)

    def assign(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        self.obs = obs
        return self.planner.assign(obs)


def _warm_map() -> OccupancyMap:
    """A small room, half of it known: the kernels' and the networks' first call, before the first real decision."""
    cells = np.full((30, 60), -1, dtype=np.int8)
    cells[:, :30] = 0
    cells[[0, -1], :] = 100
    cells[:, [0, -1]] = 100
    return occupancy_from_array(cells, 0.1, (0.0, 0.0), source="warm-up")


class AreaSearchNode(Node):  # type: ignore[misc]
    """Goals for a team of robots from ``/map`` and their poses (the module docstring: topics, timing).

    Args:
        given: settings given as options of ``areasearch ros2`` (parameter name -> value): each becomes
            its parameter's value; the same parameter given another value by ``--ros-args`` or a
            parameters file is refused (ConfigError naming both).
        node_name: the node's name (``-r __node:=...`` renames it as usual).
        **node_options: rclpy's ``Node`` options (``context``, ``parameter_overrides``...).

    Raises ConfigError for a bad parameter or planner, before any topic is opened.
    """

    def __init__(self, given: Mapping[str, Any] | None = None, node_name: str = "areasearch", **node_options: Any):
        super().__init__(node_name, **node_options)
        self.settings: NodeSettings = self._declare_parameters(dict(given or {}))
        self.config = self.settings.config
        self.choice = choose_planner(self.settings.method or None, self.settings.weights or None)
        self.planner = _Watched(self.choice.planner)
        self.problems = Problems(self.get_logger().warning, self.get_logger().info)
        history = self.config.decisions.history
        self.robots = [_Robot(name, history) for name in self.settings.robots]
        self.grid: OccupancyMap | None = None
        """The last good map."""
        self.map_frame = ""
        self.targets_xy = np.zeros((0, 2))
        self.targets_frame = ""
        self.first_tried = False
        self.decisions = 0
        """Decisions published so far."""
        self.last_answer: Assignments | None = None
        self.last_seconds = 0.0
        """Time of the last decision's goal call, seconds."""
        warm = time.perf_counter()
        assign_goals(_warm_map(), [(1.05, 1.55, 0.0), (1.05, 0.75, 1.0)], self.choice.planner, [(2.0, 1.5)])
        warm = time.perf_counter() - warm

        self.create_subscription(OccupancyGrid, MAP_TOPIC, self._on_map, LATCHED)
        pose_type = PoseWithCovarianceStamped if self.settings.pose_source == "amcl" else Odometry
        pose_qos = LATCHED if self.settings.pose_source == "amcl" else STREAM
        for k, robot in enumerate(self.robots):
            self.create_subscription(
                pose_type, pose_topic(robot.name, self.settings.pose_source), partial(self._on_pose, k), pose_qos
            )
        self.create_subscription(PoseArray, TARGETS, self._on_targets, RELIABLE)
        self.goal_publishers = [self.create_publisher(PoseStamped, goal_topic(r.name), RELIABLE) for r in self.robots]
        self.markers_publisher = self.create_publisher(MarkerArray, MARKERS_TOPIC, LATCHED)
        self.status_publisher = self.create_publisher(String, STATUS_TOPIC, LATCHED)
        self.timer = self.create_timer(self.settings.period_s, self._on_timer)
        self.get_logger().info(
            f"ready: {self.choice.method} for {', '.join(self.settings.robots)} (poses from "
            f"{pose_topic('<ns>', self.settings.pose_source)}), a decision every {self.settings.period_s:g} s and when "
            f"a robot is within {self.settings.goal_tolerance_m:g} m of its goal; warmed in {warm:.1f} s"
        )

    # ------------------------------------------------------------------------------ parameters

    def _declare_parameters(self, given: dict[str, Any]) -> NodeSettings:
        """Declare every parameter (read-only), its value the option's when given, else the
        ``--ros-args`` / parameters-file value, else the default; the settings, checked."""
        defaults = default_values()
        values: dict[str, Any] = {}
        for name, text in PARAMETERS.items():
            option = given.get(name)
            start = defaults.get(name) if option is None else option
            descriptor = ParameterDescriptor(description=text, dynamic_typing=True, read_only=True)
            value = self.declare_parameter(name, list(start) if isinstance(start, tuple) else start, descriptor).value
            if option is not None and not _same(value, option):
                flag = "--" + name.replace("_", "-")
                raise ConfigError(
                    f"{name} given twice: {flag} {_shown(option)} and the ROS parameter {name}:={_shown(value)}; "
                    "give it once"
                )
            values[name] = value
        return node_settings(values)

    # ------------------------------------------------------------------------------ messages in

    def _on_map(self, msg: OccupancyGrid) -> None:
        result = read_map(msg, MAP_TOPIC)
        if not isinstance(result, OccupancyMap):
            self.problems.report(result, MAP_UNUSED)
            return
        self.grid = result
        self.map_frame = frame_id(msg.header)
        self._maybe_first()

    def _on_pose(self, k: int, msg: Any) -> None:
        robot = self.robots[k]
        robot.heard = True
        pose = pose_from_message(msg)
        problem = pose_problem(pose, robot.name)
        if problem is not None:
            robot.pose = None  # never plan from the pose before a bad one: it no longer holds
            self.problems.report(problem, LEFT_OUT)
            return
        robot.pose = pose
        away = self._away(robot, pose)
        if robot.armed and away is not None and away <= self.settings.goal_tolerance_m:
            robot.armed = False
            self._decide(f"{robot.name} reached its goal")
            return
        if away is not None and away > 2 * self.settings.goal_tolerance_m:
            robot.armed = True  # a goal it stood on at the decision, now left: coming back is reaching it
        self._maybe_first()

    def _away(self, robot: _Robot, pose: RobotPose) -> float | None:
        """The robot's distance from its goal, metres; None without a goal or a pose good on the map."""
        if robot.goal is None or pose_problem(pose, robot.name, self.grid, self.map_frame) is not None:
            return None
        return math.hypot(pose.x - robot.goal[0], pose.y - robot.goal[1])

    def _on_targets(self, msg: PoseArray) -> None:
        xy, frame = targets_from_message(msg)
        problem = targets_problem(xy)
        if problem is not None:
            self.problems.report(problem, TARGETS_IGNORED)
            return
        self.targets_xy, self.targets_frame = xy, frame

    def _on_timer(self) -> None:
        self._decide("period")

    def _maybe_first(self) -> None:
        """The first decision, as soon as the map and a first pose of every robot are in."""
        if not self.first_tried and self.grid is not None and all(r.pose is not None for r in self.robots):
            self.first_tried = True
            self._decide("first")

    # ------------------------------------------------------------------------------ decisions

    def _team(self, grid: OccupancyMap) -> list[int]:
        """The robots whose last pose is good on ``grid``: the others are left out, their cause logged once."""
        team = []
        for k, robot in enumerate(self.robots):
            if robot.pose is None:
                if not robot.heard:
                    topic = pose_topic(robot.name, self.settings.pose_source)
                    self.problems.notice(f"pose {robot.name}", f"{robot.name}: no pose yet on {topic}; waiting")
                continue
            problem = pose_problem(robot.pose, robot.name, grid, self.map_frame)
            if problem is not None:
                self.problems.report(problem, LEFT_OUT)
                continue
            team.append(k)
        return team

    def _decide(self, why: str) -> None:
        """One decision: goals for the robots with a good pose on the last good map, published."""
        grid = self.grid
        if grid is None:
            self.problems.notice("map", f"{MAP_TOPIC}: no usable map yet; waiting")
            return
        team = self._team(grid)
        if not team:
            return
        robots = [self.robots[k] for k in team]
        poses = np.array([(r.pose.x, r.pose.y, r.pose.yaw) for r in robots if r.pose is not None])
        targets_xy, kept, problems = usable_targets(self.targets_xy, self.targets_frame, grid, self.map_frame)
        for problem in problems:
            self.problems.report(problem, TARGET_LEFT_OUT)
        started = time.perf_counter()
        try:
            answer = assign_goals(
                grid,
                poses,
                self.planner,
                targets_xy if len(targets_xy) else None,
                [_on_map(grid, r.past_positions) for r in robots],
                [_on_map(grid, r.past_goals) for r in robots],
                config=self.config,
                seed=self.settings.seed,
                robot_names=[r.name for r in robots],
            )
        except AreaSearchError as err:  # input the goal call refuses (overlapping robots, no room for a footprint)
            self.problems.report(refused(err), NO_GOALS)
            return
        except Exception as err:  # a plug-in planner may raise anything: the node keeps running, without goals
            text = f"the planner failed: {type(err).__name__}: {' '.join(str(err).split())}"
            self.problems.report(Problem(f"failed: {type(err).__name__}", "decision", text), NO_GOALS)
            return
        self.last_seconds = time.perf_counter() - started
        self._publish(team, answer, poses, [f"target_{t}" for t in kept], grid)
        self.get_logger().debug(f"decision {self.decisions} ({why}): {len(team)} robots in {self.last_seconds:.3f} s")

    def _publish(
        self, team: list[int], answer: Assignments, poses: np.ndarray, target_ids: list[str], grid: OccupancyMap
    ) -> None:
        stamp = self.get_clock().now().to_msg()
        for k, a, pose in zip(team, answer, poses, strict=True):
            robot = self.robots[k]
            robot.past_positions.appendleft((float(pose[0]), float(pose[1])))
            robot.past_goals.appendleft(a.goal_xy)
            robot.goal = a.goal_xy
            if a.goal_xy is None:
                robot.armed = False
                continue
            # a goal the robot already stands on does not trigger the next decision until the robot has left it
            robot.armed = math.hypot(pose[0] - a.goal_xy[0], pose[1] - a.goal_xy[1]) > self.settings.goal_tolerance_m
            self.goal_publishers[k].publish(goal_message(a.goal_xy, goal_yaw(a, float(pose[2])), self.map_frame, stamp))
        names = [self.robots[k].name for k in team]
        obs = self.planner.obs
        frontiers, targets = candidate_points(obs, grid) if obs is not None else (np.zeros((0, 2)),) * 2
        self.markers_publisher.publish(marker_array(team, answer, names, frontiers, targets, self.map_frame, stamp))
        doc = assignments_json(answer, names, target_ids, self.choice.method, self.choice.record())
        doc["frame"] = self.map_frame
        self.status_publisher.publish(status_message(dumps(doc)))
        self.decisions += 1
        self.last_answer = answer


def _on_map(grid: OccupancyMap, points: Sequence[tuple[float, float] | None]) -> list[tuple[float, float] | None]:
    """A robot's past points that lie on ``grid`` (a map that changed may have lost some); a goal may be None."""
    return [p for p in points if p is None or bool(grid.contains(np.array([p]))[0])]


def _same(value: Any, option: Any) -> bool:
    if isinstance(option, (list, tuple)):
        return isinstance(value, (list, tuple)) and list(value) == list(option)
    return bool(value == option)


def _shown(value: Any) -> str:
    return " ".join(map(str, value)) if isinstance(value, (list, tuple)) else str(value)


def run(given: Mapping[str, Any], ros_args: Sequence[str] = ()) -> int:
    """Run the node until Ctrl-C (SIGINT) or SIGTERM, then shut down cleanly: exit status 0.

    ``given``: the options of ``areasearch ros2`` (parameter name -> value); ``ros_args``: what
    follows ``--ros-args`` (parameters, remappings, ``--params-file``, ``--log-level``), handed to
    rclpy. ConfigError for arguments rcl cannot parse, a bad parameter or planner."""
    argv = ["areasearch", "--ros-args", *ros_args] if ros_args else ["areasearch"]
    try:
        # the default context: rclpy's SIGINT and SIGTERM handlers wake the executor and end the spin
        rclpy.init(args=argv)
    except RuntimeError as err:  # rcl's RCLError: an argument it cannot parse
        text = str(err).split(", at ")[0]
        raise ConfigError(f"--ros-args: {text}") from None
    try:
        extra = remove_ros_args(argv)[1:]
        if extra:
            raise ConfigError(f"--ros-args: {' '.join(extra)} are not ROS arguments (after --); give them before")
        node = AreaSearchNode(given)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:
            executor.spin()
        except ExternalShutdownException:  # SIGTERM, or the context shut down
            pass
        finally:
            executor.shutdown()
            node.destroy_node()
    except KeyboardInterrupt:  # Ctrl-C, while starting or spinning
        pass
    finally:
        rclpy.try_shutdown()
    return 0
