"""What the ROS 2 node publishes, as messages: a robot's goal (``geometry_msgs/PoseStamped``, what Nav2's
navigator takes on ``goal_pose``), the decision drawn for RViz or Foxglove (``visualization_msgs/MarkerArray``)
and the status answer (``std_msgs/String``).

Markers of one decision, in the map frame (each decision first deletes the last one's):

========== ================ ==============================================
namespace  type             what
========== ================ ==============================================
goals      SPHERE           each robot's goal, in the robot's colour
labels     TEXT_VIEW_FACING the robot's namespace above its goal
paths      LINE_STRIP       each robot's planned path to its goal
frontiers  POINTS           the frontier candidates the planner chose among
targets    POINTS           the target candidates (known targets a robot can take)
========== ================ ==============================================

Imports only the message packages (not rclpy); the values come from :mod:`.convert`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import Point, PoseStamped
from std_msgs.msg import ColorRGBA, String
from visualization_msgs.msg import Marker, MarkerArray

from ..service.answer import Assignment
from .convert import quaternion_xyzw

PALETTE = (
    (0.12, 0.47, 0.71),
    (1.0, 0.5, 0.05),
    (0.17, 0.63, 0.17),
    (0.84, 0.15, 0.16),
    (0.58, 0.4, 0.74),
    (0.55, 0.34, 0.29),
    (0.89, 0.47, 0.76),
    (0.5, 0.5, 0.5),
)
"""Colour (r, g, b) of robot k of the node's robots (matplotlib's tab10), one per robot up to 8."""
FRONTIER_RGB = (0.3, 0.75, 0.93)
TARGET_RGB = (0.9, 0.1, 0.1)


def goal_message(goal_xy: tuple[float, float], yaw: float, frame: str, stamp: Any) -> PoseStamped:
    """A goal pose in ``frame`` at ``goal_xy`` (metres), heading ``yaw`` (radians)."""
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.header.stamp = stamp
    msg.pose.position.x, msg.pose.position.y = float(goal_xy[0]), float(goal_xy[1])
    q = msg.pose.orientation
    q.x, q.y, q.z, q.w = quaternion_xyzw(yaw)
    return msg


def status_message(text: str) -> String:
    msg = String()
    msg.data = text
    return msg


def _marker(ns: str, k: int, kind: int, frame: str, stamp: Any, rgb: Sequence[float], alpha: float = 1.0) -> Marker:
    m = Marker()
    m.header.frame_id = frame
    m.header.stamp = stamp
    m.ns, m.id, m.type, m.action = ns, k, kind, Marker.ADD
    m.pose.orientation.w = 1.0
    m.color = ColorRGBA(r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=alpha)
    return m


def _points(xy: Sequence[Sequence[float]] | np.ndarray, z: float = 0.0) -> list[Point]:
    return [Point(x=float(x), y=float(y), z=z) for x, y in xy]


def marker_array(
    robots: Sequence[int],
    assignments: Sequence[Assignment],
    names: Sequence[str],
    frontiers_xy: np.ndarray,
    targets_xy: np.ndarray,
    frame: str,
    stamp: Any,
) -> MarkerArray:
    """The markers of one decision: ``assignments[i]`` is the goal of robot ``robots[i]`` (its index
    among the node's robots: marker id and colour) named ``names[i]``; the candidates in metres."""
    out = MarkerArray()
    clear = Marker()
    clear.header.frame_id = frame
    clear.action = Marker.DELETEALL
    out.markers.append(clear)
    for k, a, name in zip(robots, assignments, names, strict=True):
        if a.goal_xy is None:
            continue
        rgb = PALETTE[k % len(PALETTE)]
        goal = _marker("goals", k, Marker.SPHERE, frame, stamp, rgb)
        goal.pose.position.x, goal.pose.position.y, goal.pose.position.z = a.goal_xy[0], a.goal_xy[1], 0.15
        goal.scale.x = goal.scale.y = goal.scale.z = 0.3
        label = _marker("labels", k, Marker.TEXT_VIEW_FACING, frame, stamp, rgb)
        label.pose.position.x, label.pose.position.y, label.pose.position.z = a.goal_xy[0], a.goal_xy[1], 0.5
        label.scale.z = 0.25
        label.text = name
        path = _marker("paths", k, Marker.LINE_STRIP, frame, stamp, rgb, 0.8)
        path.scale.x = 0.05
        path.points = _points(a.path_xy, 0.05)
        out.markers += [goal, label, path]
    for ns, xy, rgb in (("frontiers", frontiers_xy, FRONTIER_RGB), ("targets", targets_xy, TARGET_RGB)):
        if len(xy) == 0:
            continue
        points = _marker(ns, 0, Marker.POINTS, frame, stamp, rgb, 0.9)
        points.scale.x = points.scale.y = 0.12
        points.points = _points(xy, 0.02)
        out.markers.append(points)
    return out
