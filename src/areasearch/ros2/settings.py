"""The ROS 2 node's settings: its ROS parameters as one typed, checked :class:`NodeSettings`.

Every setting is a ROS parameter of the node (``--ros-args -p period_s:=2.0``, a parameters file, a
launch file's ``parameters``) and an option of ``areasearch ros2`` (``--period-s 2.0``); the option
gives the parameter's value, and the same setting given both ways with different values is refused,
naming both (one would silently win). :data:`PARAMETERS` describes each one (the docs' table).
Nothing here imports rclpy: the checks are plain Python, tested without ROS.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ..config import CAMERA_LIMITS, MAX_ROBOTS, ROBOT_LIMITS, SearchConfig, override
from ..errors import ConfigError
from ..inputs import is_real, short

POSE_SOURCES = ("amcl", "odom")
"""Where a robot's pose comes from: ``/<ns>/amcl_pose`` (PoseWithCovarianceStamped) or ``/<ns>/odom`` (Odometry)."""
MAX_PERIOD_S = 86_400.0
"""Longest decision period, seconds (a day)."""
MIN_PERIOD_S = 0.05
"""Shortest decision period, seconds."""
MAX_TOLERANCE_M = 10.0
"""Largest goal tolerance, metres."""
_NAMESPACE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*")
_DEFAULTS = SearchConfig()


@dataclass(frozen=True)
class NodeSettings:
    """What the node does: whose goals, from which poses, with which planner, how often."""

    robots: tuple[str, ...]
    """The robots' namespaces (``r1`` -> ``/r1/amcl_pose`` in, ``/r1/goal_pose`` out), 1 to 8, in the
    order of the status answer."""
    pose_source: str = "amcl"
    """``amcl`` (``/<ns>/amcl_pose``, what Nav2's AMCL publishes) or ``odom`` (``/<ns>/odom``)."""
    method: str = ""
    """The goal planner (``areasearch methods`` lists them); empty: ``greedy``, or with ``weights`` the
    network they describe."""
    weights: str = ""
    """Your own weights, ``PREFIX.safetensors`` + ``PREFIX.json``, for the learned ``method``; empty: none."""
    period_s: float = 5.0
    """Seconds between decisions (the node also decides as soon as a robot reaches its goal)."""
    goal_tolerance_m: float = 0.25
    """A robot within this distance of its goal has reached it (Nav2's default ``xy_goal_tolerance``), metres."""
    seed: int = 0
    """Seed of the planner's random draws (same input and seed, same goals)."""
    radius_m: float = _DEFAULTS.world.robot.radius_m
    """Robot footprint radius, metres."""
    sensor_range_m: float = _DEFAULTS.world.camera.max_range_m
    """Sensor range for the information gain of a frontier, metres."""

    @property
    def config(self) -> SearchConfig:
        """The planning settings: the defaults with this footprint and sensor range."""
        changes = {"world.robot.radius_m": self.radius_m, "world.camera.max_range_m": self.sensor_range_m}
        return override(SearchConfig(), **changes).validate()


PARAMETERS: dict[str, str] = {
    "robots": "robots' namespaces, 1-8 (string array; required)",
    "pose_source": "`amcl` (`/<ns>/amcl_pose`) or `odom` (`/<ns>/odom`)",
    "method": "goal planner; empty: `greedy` (`areasearch methods` lists them)",
    "weights": "your own weights `PREFIX` for the learned `method`; empty: none",
    "period_s": "seconds between decisions",
    "goal_tolerance_m": "a robot this near its goal has reached it: re-plan at once",
    "seed": "seed of the planner's random draws",
    "radius_m": "robot footprint radius, metres",
    "sensor_range_m": "sensor range for a frontier's information gain, metres",
}
"""The node's ROS parameters (the fields of :class:`NodeSettings`) with one line each."""


def default_values() -> dict[str, Any]:
    """Each parameter's default, as a ROS parameter value (``robots`` has none)."""
    defaults = NodeSettings(robots=())
    return {name: getattr(defaults, name) for name in PARAMETERS if name != "robots"}


def _number(name: str, value: Any, low: float, high: float, *, low_open: bool = False) -> float:
    """``value`` as a finite float in [low, high] (``(low, high]``), or ConfigError naming the parameter."""
    bounds = f"{'(' if low_open else '['}{low:g}, {high:g}]"
    if not is_real(value) or not math.isfinite(float(value)):
        raise ConfigError(f"parameter {name} must be a number in {bounds}, got {short(value)}")
    number = float(value)
    if number < low or (low_open and number == low) or number > high:
        raise ConfigError(f"parameter {name} must be a number in {bounds}, got {number:g}")
    return number


def _text(name: str, value: Any) -> str:
    if not isinstance(value, str):
        raise ConfigError(f"parameter {name} must be a string, got {short(value)}")
    return value.strip()


def check_robots(value: Any) -> tuple[str, ...]:
    """The robots' namespaces: 1 to :data:`~areasearch.config.MAX_ROBOTS` distinct ROS names
    (``r1``, ``fleet/tb3_0``; a leading or trailing ``/`` is dropped), or ConfigError naming the parameter."""
    if value is None or (isinstance(value, (list, tuple)) and len(value) == 0):
        raise ConfigError("no robots: give their namespaces, --robots r1 r2 r3 or the ROS parameter robots")
    if isinstance(value, str) or not isinstance(value, (list, tuple)):
        raise ConfigError(f"parameter robots must be a list of namespaces, got {short(value)}")
    names = []
    for item in value:
        name = item.strip().strip("/") if isinstance(item, str) else None
        if name is None or not _NAMESPACE.fullmatch(name):
            raise ConfigError(
                f"parameter robots: {short(item)} is not a ROS namespace (letters, digits, _ and /, "
                "not starting with a digit)"
            )
        names.append(name)
    if len(names) > MAX_ROBOTS:
        raise ConfigError(f"parameter robots: {len(names)} robots; the planners plan for at most {MAX_ROBOTS}")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError(f"parameter robots: {', '.join(twice)} given twice")
    return tuple(names)


def node_settings(values: Mapping[str, Any]) -> NodeSettings:
    """The settings from the parameters' values (``None``: the default), each checked: ConfigError
    naming the parameter at fault. An unknown name is refused too."""
    unknown = sorted(set(values) - set(PARAMETERS))
    if unknown:
        raise ConfigError(f"unknown parameter(s): {', '.join(unknown)}; known: {', '.join(PARAMETERS)}")
    given = {k: v for k, v in values.items() if v is not None}
    defaults = NodeSettings(robots=())
    pose_source = _text("pose_source", given.get("pose_source", defaults.pose_source))
    if pose_source not in POSE_SOURCES:
        raise ConfigError(f"parameter pose_source must be one of {', '.join(POSE_SOURCES)}, got {short(pose_source)}")
    seed = given.get("seed", defaults.seed)
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise ConfigError(f"parameter seed must be a non-negative integer, got {short(seed)}")
    return NodeSettings(
        robots=check_robots(given.get("robots")),
        pose_source=pose_source,
        method=_text("method", given.get("method", defaults.method)),
        weights=_text("weights", given.get("weights", defaults.weights)),
        period_s=_number("period_s", given.get("period_s", defaults.period_s), MIN_PERIOD_S, MAX_PERIOD_S),
        goal_tolerance_m=_number(
            "goal_tolerance_m", given.get("goal_tolerance_m", defaults.goal_tolerance_m), 0.0, MAX_TOLERANCE_M,
            low_open=True,
        ),
        seed=seed,
        radius_m=_number("radius_m", given.get("radius_m", defaults.radius_m), 0.0, ROBOT_LIMITS["radius_m"],
                         low_open=True),
        sensor_range_m=_number(
            "sensor_range_m", given.get("sensor_range_m", defaults.sensor_range_m), 0.0,
            CAMERA_LIMITS["max_range_m"], low_open=True,
        ),
    )  # fmt: skip
