"""Typed, frozen configuration of the search world, one dataclass per concern.

Every field is documented where it is declared, with its unit. Derived quantities are properties.
Variants come from :func:`dataclasses.replace` or :func:`override`, which also accepts dotted keys
(``"camera.width_px"``) so that entry points can take ``**overrides``. The command line's ``--set
KEY=VALUE`` options are read by :func:`parse_settings` and applied to a :class:`SearchConfig` by
:func:`search_config`; an environment's keyword arguments become its configuration in
:func:`env_config`.

The parts: :mod:`.world` (robots, camera, coverage protocol, targets, reward: :class:`WorldConfig`),
:mod:`.noise` (motion and sensing noise, target detection: the world's ``noise`` and ``detection``
groups), :mod:`.comm` (communication between the robots: the world's ``comm`` group), :mod:`.mapping` (the mapper's
occupancy model: the world's ``mapping`` group), :mod:`.realism`
(named presets of those groups' settings: ``--realism low|medium|high``), :mod:`.search`
(candidate goals, action planner, decisions: :class:`SearchConfig`), :mod:`.settings` (overrides and
``--set`` settings), :mod:`.checks` (the field checks). Every name is imported from here,
``areasearch.config``.
"""

from __future__ import annotations

from .comm import COMM_MODELS, CommConfig, CommModel
from .mapping import OCCUPANCY_MODELS, MappingConfig, OccupancyModel
from .noise import DETECTION_MODELS, DetectionConfig, DetectionModel, NoiseConfig
from .realism import (
    NO_REALISM,
    REALISM_KEY,
    REALISM_NAMES,
    REALISM_PRESETS,
    realism_config,
    realism_keywords,
    realism_preset,
    realism_settings,
    split_realism,
)
from .search import CandidateConfig, DecisionConfig, PathConfig, SearchConfig
from .settings import (
    SEARCH_GROUPS,
    env_config,
    override,
    parse_settings,
    search_config,
    search_key,
    search_settings,
)
from .world import (
    CAMERA_LIMITS,
    FPS_RANGE,
    MAX_REWARD,
    MAX_ROBOTS,
    MAX_STEPS,
    PROTOCOLS,
    ROBOT_LIMITS,
    CameraConfig,
    Protocol,
    ProtocolName,
    RewardConfig,
    RobotConfig,
    TargetConfig,
    WorldConfig,
)

__all__ = [
    "CAMERA_LIMITS",
    "COMM_MODELS",
    "DETECTION_MODELS",
    "FPS_RANGE",
    "MAX_REWARD",
    "MAX_ROBOTS",
    "MAX_STEPS",
    "NO_REALISM",
    "OCCUPANCY_MODELS",
    "PROTOCOLS",
    "REALISM_KEY",
    "REALISM_NAMES",
    "REALISM_PRESETS",
    "ROBOT_LIMITS",
    "SEARCH_GROUPS",
    "CameraConfig",
    "CandidateConfig",
    "CommConfig",
    "CommModel",
    "DecisionConfig",
    "DetectionConfig",
    "DetectionModel",
    "MappingConfig",
    "NoiseConfig",
    "OccupancyModel",
    "PathConfig",
    "Protocol",
    "ProtocolName",
    "RewardConfig",
    "RobotConfig",
    "SearchConfig",
    "TargetConfig",
    "WorldConfig",
    "env_config",
    "override",
    "parse_settings",
    "realism_config",
    "realism_keywords",
    "realism_preset",
    "realism_settings",
    "search_config",
    "search_key",
    "search_settings",
    "split_realism",
]
