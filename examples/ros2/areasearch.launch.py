"""Launch the areasearch node for a team of Nav2 robots: ``ros2 launch examples/ros2/areasearch.launch.py``.

The node is ``areasearch ros2`` of the Python environment areasearch is installed in (``pip install
'areasearch[ros2]'``; its own rclpy from PyPI, so its Python need not be the ROS installation's): give
its path with ``executable:=/path/to/venv/bin/areasearch`` unless that environment's ``bin`` is on the
PATH. The launch file itself needs a ROS 2 installation's ``launch`` and ``launch_ros``.

    ros2 launch examples/ros2/areasearch.launch.py method:=dahgnn period_s:=5.0
    ros2 launch examples/ros2/areasearch.launch.py map_topic:=/merged_map use_sim_time:=true

Parameters come from ``areasearch.yaml`` beside this file (the robots' namespaces, the planner, the
timing), with the launch arguments over them.
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

HERE = Path(__file__).resolve().parent


def generate_launch_description() -> LaunchDescription:
    arguments = {
        "executable": ("areasearch", "the areasearch command (a path into its virtualenv, or on the PATH)"),
        "method": ("dahgnn", "goal planner: any name 'areasearch methods' lists"),
        "period_s": ("5.0", "seconds between decisions"),
        "map_topic": ("/map", "the team's map (nav_msgs/OccupancyGrid, transient local)"),
        "use_sim_time": ("false", "follow /clock (a simulator)"),
    }
    config = {name: LaunchConfiguration(name) for name in arguments}
    node = Node(
        executable=config["executable"],  # no package: areasearch is a Python program, not a ROS package
        arguments=["ros2"],  # launch_ros adds --ros-args with the name, the parameters and the remappings
        name="areasearch",
        output="screen",
        parameters=[
            str(HERE / "areasearch.yaml"),
            {
                "method": config["method"],
                "period_s": ParameterValue(config["period_s"], value_type=float),
                "use_sim_time": ParameterValue(config["use_sim_time"], value_type=bool),
            },
        ],
        remappings=[("/map", config["map_topic"])],
    )
    declared = [DeclareLaunchArgument(name, default_value=d, description=text) for name, (d, text) in arguments.items()]
    return LaunchDescription([*declared, node])
