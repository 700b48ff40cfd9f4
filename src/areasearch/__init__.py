"""areasearch: multi-robot collaborative area search (explore and cover), after DA-HGNN.

Pipeline: scene -> world -> depth -> mapper -> candidates -> graph -> planner -> goals -> paths
-> actions. Entry points: :func:`parallel_env` (PettingZoo, one primitive action per robot per
step), ``gymnasium.make("areasearch/AreaSearch-v0", map=..., num_robots=...)`` (one long-term goal
per robot per decision), the ``areasearch`` command line. Both environments take ``realism="low"``,
``"medium"`` or ``"high"``, a preset of the world's imperfections (:data:`areasearch.config.REALISM_PRESETS`).
"""

from __future__ import annotations

import gymnasium

from ._version import __version__ as __version__
from .config import (
    CameraConfig,
    CandidateConfig,
    DecisionConfig,
    PathConfig,
    RewardConfig,
    RobotConfig,
    SearchConfig,
    TargetConfig,
    WorldConfig,
)
from .envs.parallel import AreaSearchParallelEnv, env, parallel_env
from .errors import AreaSearchError, ConfigError, MapError
from .sim.scene import Scene, load_ros_yaml, load_scene, size_class_of
from .sim.world import Action, World

GOAL_ENV_ID = "areasearch/AreaSearch-v0"
"""Gymnasium id of the high-level (one long-term goal per robot per decision) environment."""

if GOAL_ENV_ID not in gymnasium.registry:
    gymnasium.register(id=GOAL_ENV_ID, entry_point="areasearch.envs.goal:AreaSearchEnv")

__all__ = [
    "GOAL_ENV_ID",
    "Action",
    "AreaSearchError",
    "AreaSearchParallelEnv",
    "CameraConfig",
    "CandidateConfig",
    "ConfigError",
    "DecisionConfig",
    "MapError",
    "PathConfig",
    "RewardConfig",
    "RobotConfig",
    "Scene",
    "SearchConfig",
    "TargetConfig",
    "World",
    "WorldConfig",
    "env",
    "load_ros_yaml",
    "load_scene",
    "parallel_env",
    "size_class_of",
]
