"""The ROS 2 node: goals for a robot team from its ``/map`` and its robots' poses, published for Nav2.

``areasearch ros2`` (``pip install 'areasearch[ros2]'``: rclpy and the message packages from PyPI,
no ROS installation needed) runs :class:`.node.AreaSearchNode`: it subscribes to the map
(``nav_msgs/OccupancyGrid``), each robot's pose (AMCL's or odometry) and known targets, assigns one
goal per robot with any goal planner through :func:`areasearch.service.assign.assign_goals`, every
decision period and as soon as a robot reaches its goal, and publishes each goal on
``/<ns>/goal_pose``, markers and the JSON answer ``areasearch assign`` prints.

The parts: :mod:`.settings` (the ROS parameters, checked), :mod:`.convert` (messages to the goal
call's inputs and back, pure), :mod:`.checks` (bad messages, logged once per cause),
:mod:`.messages` (the messages published) and :mod:`.node` (the node and :func:`.node.run`). Only
:mod:`.node` and :mod:`.messages` import rclpy or the message packages; :func:`require_ros2` says,
in one line, when they are missing.
"""

from __future__ import annotations

from ..errors import ConfigError

ROS2_EXTRA = "the ROS 2 node needs the ros2 extra: pip install 'areasearch[ros2]'"
"""The message of a missing rclpy or message package."""


def require_ros2() -> None:
    """ConfigError (:data:`ROS2_EXTRA`, with the import error) unless rclpy and the message
    packages the node uses import."""
    try:
        import geometry_msgs.msg  # noqa: F401
        import nav_msgs.msg  # noqa: F401
        import rclpy  # noqa: F401
        import std_msgs.msg  # noqa: F401
        import visualization_msgs.msg  # noqa: F401
    except ImportError as err:
        raise ConfigError(f"{ROS2_EXTRA} ({err})") from None
