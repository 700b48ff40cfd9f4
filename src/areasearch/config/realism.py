"""Realism presets: named sets of the world's imperfection settings (the ``noise``, ``detection``,
``comm`` and ``mapping`` groups of :class:`~areasearch.config.WorldConfig`), so that a run under "a realistic
world" is one word (``--realism medium``, ``parallel_env(realism="medium")``) rather than a dozen ``--set``
options, and the same word means the same world everywhere.

Each preset is a mapping of settings by their full ``--set`` keys (``world.noise.forward``, the keys of
:func:`areasearch.config.search_settings`) to values; adding a setting to a preset is one line of
:data:`REALISM_PRESETS`. A preset is applied under the settings given with it: **an explicit setting wins
over the preset's value** (``--realism medium --set noise.forward=0.2`` drives with 0.2, the rest of
``medium`` as it is), on the command line (:func:`realism_settings`) and in the environments' keywords
(:func:`realism_keywords`).

The presets (sources: NCM = Ye et al., CVPR 2022, "Multi-Robot Active Mapping via Neural Bipartite Graph
Matching", code siyandong/NeuralCoMapping, on iGibson; IR2 = Tan, Ma, Liang, Cao and Sartoretti, IROS 2024,
code marmotlab/IR2-Multi-Robot-RL-Exploration; "ours" where neither gives a value):

``none``
    No settings: the default perfect world (no noise, certain detection, full communication), bit for bit.

``low``: a good robot in a small building.
    * ``noise.forward`` and ``noise.turn`` 0.025: NCM's action noise, ±2.5 % on the wheel commands.
    * ``noise.odometry_forward`` and ``noise.odometry_turn`` 0.005 (0.5 %): ours, wheel odometry on a
      flat indoor floor drifting about 1 % of the distance after some dozens of moves.
    * ``noise.depth`` 0.005 (0.5 % of the depth, 1.6 cm at the camera's 3.2 m): ours, a good
      structured-light or time-of-flight sensor indoors.
    * ``noise.dropout`` 0.01: ours (NCM drops depth pixels and gives no public rate).
    * ``detection`` ``constant``, ``p_near`` 0.95: ours, a detector that misses one frame in twenty.
    * ``comm`` ``disc``, ``range_m`` 10: ours, a radio that reaches across a flat but not a building.

``medium``: twice ``low``'s noise, detection that fades with the distance, IR2's radio.
    * ``noise.forward`` and ``noise.turn`` 0.05: twice NCM's, a worn or slipping drive (ours).
    * ``noise.odometry_forward`` and ``noise.odometry_turn`` 0.01, ``noise.depth`` 0.01,
      ``noise.dropout`` 0.05: ours, twice ``low``'s (five times its dropout: reflective and dark surfaces).
    * ``detection`` ``linear``, ``p_near`` 0.95, ``p_far`` 0.6: ours, a detector that finds a target close
      by nearly always and at the camera's range in three frames of five.
    * ``comm`` ``signal`` with the :class:`~areasearch.config.CommConfig` defaults: IR2's signal-strength
      model with its own parameters (-20 dBm sent, -70 dBm threshold, walls losing faster than free space).

``high``: a hard world.
    * ``noise.forward`` and ``noise.turn`` 0.1: four times NCM's (ours).
    * ``noise.odometry_forward`` and ``noise.odometry_turn`` 0.02, ``noise.depth`` 0.02,
      ``noise.dropout`` 0.1: ours, twice ``medium``'s.
    * ``detection`` ``linear``, ``p_near`` 0.9, ``p_far`` 0.3: ours.
    * ``comm`` ``signal``, ``tx_power_dbm`` -25: IR2's model with a weaker radio, 5 dB less than IR2's -20 dBm
      (ours), so links through walls break sooner.

Every preset but ``none`` also maps with ``mapping.occupancy`` ``log_odds`` (the probabilistic occupancy
grid of OctoMap, Hornung et al., Autonomous Robots 2013, :class:`~areasearch.config.MappingConfig`): a real
robot with a noisy depth sensor maps that way, and the sticky rule of the perfect world would keep every
wall point that fell short as a phantom obstacle.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from ..errors import ConfigError
from .checks import brief
from .search import SearchConfig
from .settings import search_config, search_key, search_settings

REALISM_KEY = "realism"
"""The name of the preset among an environment's keywords and a training run's ``rollout.env`` settings."""

NO_REALISM = "none"
"""The preset of no settings: the default perfect world."""


def _preset(**settings: Any) -> Mapping[str, Any]:
    """A preset's settings, ``world.``-prefixed keys from the ``__``-separated keyword names, read only."""
    return MappingProxyType({f"world.{key.replace('__', '.')}": value for key, value in settings.items()})


REALISM_PRESETS: Mapping[str, Mapping[str, Any]] = MappingProxyType(
    {
        NO_REALISM: _preset(),
        "low": _preset(
            noise__forward=0.025,
            noise__turn=0.025,
            noise__odometry_forward=0.005,
            noise__odometry_turn=0.005,
            noise__depth=0.005,
            noise__dropout=0.01,
            detection__model="constant",
            detection__p_near=0.95,
            comm__model="disc",
            comm__range_m=10.0,
            mapping__occupancy="log_odds",
        ),
        "medium": _preset(
            noise__forward=0.05,
            noise__turn=0.05,
            noise__odometry_forward=0.01,
            noise__odometry_turn=0.01,
            noise__depth=0.01,
            noise__dropout=0.05,
            detection__model="linear",
            detection__p_near=0.95,
            detection__p_far=0.6,
            comm__model="signal",
            mapping__occupancy="log_odds",
        ),
        "high": _preset(
            noise__forward=0.1,
            noise__turn=0.1,
            noise__odometry_forward=0.02,
            noise__odometry_turn=0.02,
            noise__depth=0.02,
            noise__dropout=0.1,
            detection__model="linear",
            detection__p_near=0.9,
            detection__p_far=0.3,
            comm__model="signal",
            comm__tx_power_dbm=-25.0,
            mapping__occupancy="log_odds",
        ),
    }
)
"""The realism presets by name: each a mapping of full ``--set`` keys to values (module docstring)."""

REALISM_NAMES = tuple(REALISM_PRESETS)
"""The preset names, from the perfect world to the hardest: ``none``, ``low``, ``medium``, ``high``."""


def realism_preset(name: object) -> Mapping[str, Any]:
    """The settings of the preset ``name`` (full keys); ConfigError naming the valid names for another."""
    if not isinstance(name, str) or name not in REALISM_PRESETS:
        names = ", ".join(repr(n) for n in REALISM_NAMES)
        raise ConfigError(f"realism must be one of {names}, got {brief(name)}")
    return REALISM_PRESETS[name]


def _covered(key: str, given: set[str]) -> bool:
    """A preset key (full) that a given setting sets: the same key, or a group holding it (``world.noise``)."""
    return any(key == other or key.startswith(f"{other}.") for other in given)


def realism_settings(name: object, settings: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The settings of preset ``name`` with ``settings`` (``--set`` settings, any key form
    :func:`~areasearch.config.search_settings` takes) over them: the explicit settings win. By their
    full keys, sorted, as :func:`~areasearch.config.search_settings` gives them. ConfigError for an
    unknown preset or key."""
    preset = realism_preset(name)
    given = search_settings(settings or {})
    kept = {key: value for key, value in preset.items() if not _covered(key, set(given))}
    return search_settings({**kept, **given})


def realism_config(
    name: object, settings: Mapping[str, Any] | None = None, base: SearchConfig | None = None
) -> SearchConfig:
    """``base`` (default :class:`SearchConfig`) with preset ``name`` applied and ``settings`` over it,
    validated (:func:`~areasearch.config.search_config`)."""
    return search_config(realism_settings(name, settings), base)


def realism_keywords(name: object, keywords: Mapping[str, Any]) -> dict[str, Any]:
    """An environment's keyword settings (world keys relative to the world: ``noise__forward``,
    ``**{"noise.forward": 0.1}``, ``noise=NoiseConfig(...)``; ``candidates.`` / ``paths.`` / ``decisions.``
    keys) with the settings of preset ``name`` added where no keyword sets them: the keywords win.
    ConfigError for an unknown preset."""
    preset = realism_preset(name)
    given = {search_key(str(key)) for key in keywords}
    added = {key.removeprefix("world."): value for key, value in preset.items() if not _covered(key, given)}
    return {**added, **keywords}


def split_realism(settings: Mapping[str, Any]) -> tuple[Any, dict[str, Any]]:
    """The preset named among ``settings`` (its :data:`REALISM_KEY` entry; :data:`NO_REALISM` when it
    has none), not checked, and the other settings."""
    rest = {key: value for key, value in settings.items() if key != REALISM_KEY}
    return settings.get(REALISM_KEY, NO_REALISM), rest
