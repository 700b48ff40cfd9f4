"""areasearch: multi-robot collaborative area search (explore and cover), after DA-HGNN.

Pipeline: scene -> world -> depth -> mapper -> candidates -> graph -> planner -> goals -> paths
-> actions. Entry points: :func:`parallel_env` (PettingZoo), the ``areasearch`` command line.
"""

from __future__ import annotations

from .config import CameraConfig, RewardConfig, RobotConfig, TargetConfig, WorldConfig
from .env import AreaSearchParallelEnv, env, parallel_env
from .errors import AreaSearchError, ConfigError, MapError
from .scene import Scene, load_ros_yaml, load_scene, size_class_of
from .world import Action, World

__version__ = "0.1.0"

__all__ = [
    "Action",
    "AreaSearchError",
    "AreaSearchParallelEnv",
    "CameraConfig",
    "ConfigError",
    "MapError",
    "RewardConfig",
    "RobotConfig",
    "Scene",
    "TargetConfig",
    "World",
    "WorldConfig",
    "env",
    "load_ros_yaml",
    "load_scene",
    "parallel_env",
    "size_class_of",
]
