"""ROS 2 messages as the goal call's inputs, and its answer as what the node publishes: pure functions.

In: ``nav_msgs/OccupancyGrid`` -> :class:`~areasearch.service.grid.OccupancyMap` (:func:`grid_from_message`),
``PoseWithCovarianceStamped`` / ``Odometry`` -> :class:`RobotPose` (:func:`pose_from_message`: both hold
``header`` and ``pose.pose``), ``geometry_msgs/PoseArray`` -> (T, 2) target positions
(:func:`targets_from_message`). Out: a goal's heading (:func:`goal_yaw`), a quaternion for a yaw
(:func:`quaternion_xyzw`), the decision's frontier and target candidates in metres
(:func:`candidate_points`).

The grid follows the ROS message convention that :mod:`areasearch.service.occupancy_msg` reads from
JSON, here from the message's own buffer (a 3.3 M-cell map in about 15 ms, without a Python list):
``data`` row-major, row 0 at the origin, -1 unknown and 0-100 occupancy read with map_server's
thresholds (:func:`areasearch.service.grid.occupancy_from_array`); the origin's orientation must be
level and of yaw 0 (:func:`areasearch.sim.mapfiles.check_origin`). Units: metres, radians, the
map frame. Messages are read by their fields only (duck typing), so nothing here imports rclpy or a
message package: the functions are tested without ROS.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from ..errors import MapError
from ..planning.candidates import CandidateKind
from ..service.answer import Assignment
from ..service.grid import OccupancyMap, occupancy_from_array
from ..service.occupancy_msg import origin_yaw
from ..sim.mapfiles import check_origin, check_resolution


class RobotPose(NamedTuple):
    """A robot's pose as a message gave it (not yet checked: values may be NaN)."""

    x: float
    """Metres, in :attr:`frame`."""
    y: float
    yaw: float
    """Radians; NaN for a quaternion that is not finite or of norm zero."""
    frame: str
    """The header's ``frame_id`` (:func:`frame_id`)."""


def frame_id(header: Any) -> str:
    """A header's ``frame_id`` as tf2 compares them: a leading ``/`` dropped (ROS 1's ``/map`` is ``map``)."""
    return str(header.frame_id).strip().lstrip("/")


def yaw_of(q: Any) -> float:
    """The yaw (radians) of a quaternion with fields x, y, z, w; NaN when it is not finite or of norm
    zero (no rotation can be read from it)."""
    x, y, z, w = (float(q.x), float(q.y), float(q.z), float(q.w))
    norm = math.hypot(x, y, z, w)
    if not math.isfinite(norm) or norm == 0.0:
        return math.nan
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quaternion_xyzw(yaw: float) -> tuple[float, float, float, float]:
    """The quaternion (x, y, z, w) of a rotation by ``yaw`` radians about z."""
    return (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))


def grid_from_message(msg: Any, source: str = "/map") -> OccupancyMap:
    """The occupancy map of a ``nav_msgs/OccupancyGrid`` message; MapError naming what is wrong (no
    cell, a size that does not match ``data``, a value outside -1..100, a resolution or origin the map
    files may not have, a map with no free cell)."""
    info = msg.info
    width, height = int(info.width), int(info.height)
    values = np.asarray(msg.data)
    if width * height == 0 or values.size == 0:
        raise MapError(f"{source}: the map is empty ({width} x {height} cells, {values.size} values)")
    if values.size != width * height:
        raise MapError(f"{source}: data holds {values.size:,} cells; info.width x info.height is {width} x {height}")
    if values.dtype.kind not in "iu":
        raise MapError(f"{source}: data must hold integers (-1 unknown, 0-100 occupancy), got {values.dtype}")
    yaw = origin_yaw(info.origin.orientation, f"{source}: info.origin.orientation")
    position = info.origin.position
    origin = check_origin(source, [float(position.x), float(position.y), 0.0 if abs(yaw) < 1e-9 else yaw])
    # the message holds a float32: read it as the shortest decimal that rounds to it (a YAML's 0.05, not
    # 0.0500000007), so that goals equal those of the map's own files
    resolution = check_resolution(source, float(str(np.float32(info.resolution))))
    return occupancy_from_array(values.reshape(height, width), resolution, origin, source=source)


def pose_from_message(msg: Any) -> RobotPose:
    """The pose of a ``PoseWithCovarianceStamped`` (AMCL) or an ``Odometry`` message: both carry
    ``header`` and ``pose.pose``."""
    pose = msg.pose.pose
    return RobotPose(float(pose.position.x), float(pose.position.y), yaw_of(pose.orientation), frame_id(msg.header))


def targets_from_message(msg: Any) -> tuple[np.ndarray, str]:
    """(T, 2) positions (x, y), metres, of a ``geometry_msgs/PoseArray``'s poses, and its frame."""
    xy = np.array([(float(p.position.x), float(p.position.y)) for p in msg.poses], dtype=np.float64)
    return xy.reshape(-1, 2), frame_id(msg.header)


def goal_yaw(assignment: Assignment, robot_yaw: float) -> float:
    """The heading to arrive with: along the last step of the planned path (the robot drives on in the
    direction it came, towards the unknown beyond a frontier), else the robot's own heading."""
    path = assignment.path_xy
    if len(path) >= 2:
        (x0, y0), (x1, y1) = path[-2], path[-1]
        if math.hypot(x1 - x0, y1 - y0) > 1e-9:
            return math.atan2(y1 - y0, x1 - x0)
    return robot_yaw


def candidate_points(obs: dict[str, np.ndarray], grid: OccupancyMap) -> tuple[np.ndarray, np.ndarray]:
    """(F, 2) frontier and (T, 2) target candidates of a decision's observation, map-frame metres
    (cell centres): what the planner chose among."""
    real = obs["candidate_mask"].astype(bool)
    rows = obs["candidates"][real]  # (K, 5): cell row, cell column, kind, size, gain
    cells = rows[:, :2].astype(np.int64)
    xy = grid.cell_to_world(cells).reshape(-1, 2)
    kind = rows[:, 2].astype(np.int64)
    return xy[kind == int(CandidateKind.FRONTIER)], xy[kind == int(CandidateKind.TARGET)]
