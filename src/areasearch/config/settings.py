"""Settings applied to a configuration: :func:`override` (a copy with fields replaced, dotted or ``__``
keys reaching nested configs), the command line's ``--set KEY=VALUE`` (:func:`parse_settings`,
:func:`search_settings`, :func:`search_config`), and :func:`env_config`, the one place where an
environment's keyword arguments (``parallel_env(protocol="passby", camera__width_px=96)``,
``gymnasium.make(..., **{"camera.width_px": 96})``) become its typed configuration."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

from ..errors import ConfigError
from ..inputs import int_digits_message, is_int_digits_error
from .checks import brief
from .search import SearchConfig
from .world import WorldConfig


def override(config: Any, **changes: Any) -> Any:
    """Return a copy of a config dataclass with fields replaced.

    Keys may be dotted (``"camera.width_px"``) or use a double underscore (``camera__width_px``)
    to reach nested configs. Unknown keys raise :class:`ConfigError`.
    """
    nested: dict[str, dict[str, Any]] = {}
    flat: dict[str, Any] = {}
    names = {f.name for f in dataclasses.fields(config)}
    for key, value in changes.items():
        head, sep, rest = key.replace("__", ".").partition(".")
        if head not in names:
            raise ConfigError(f"unknown setting {brief(key)} for {type(config).__name__}; known: {sorted(names)}")
        if sep:
            nested.setdefault(head, {})[rest] = value
        else:
            flat[head] = value
    for head, value in flat.items():
        current = getattr(config, head)
        if dataclasses.is_dataclass(current) and not isinstance(value, type(current)):
            raise ConfigError(
                f"setting {head!r} is a group of settings; set its fields ({head}.<field>=...), got {brief(value)}"
            )
    for head, sub in nested.items():
        inner = flat.get(head, getattr(config, head))
        if not dataclasses.is_dataclass(inner):
            raise ConfigError(f"setting {head!r} has no sub-fields")
        flat[head] = override(inner, **sub)
    return dataclasses.replace(config, **flat)


# ---------------------------------------------------------------------------------- --set KEY=VALUE


def parse_settings(pairs: Iterable[str]) -> dict[str, Any]:
    """``KEY=VALUE`` strings (the command line's ``--set`` options) -> ``{KEY: value}``.

    A value is read as JSON where it is JSON (numbers, ``true`` / ``false``, ``null``, lists), else
    kept as text; a later pair with the same key wins. Keys are not checked here (each command knows
    its settings: :func:`search_settings` for the world, the training config for ``train``).
    ConfigError, naming the pair, for a pair without ``=``, an empty key or value, a key with spaces,
    and a non-finite number (``nan``, ``inf``, ``1e999``).
    """
    settings: dict[str, Any] = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        key = key.strip()
        if not sep or not key or not text.strip() or any(c.isspace() for c in key):
            raise ConfigError(f"--set {brief(pair)}: expected KEY=VALUE, e.g. --set robot.radius_m=0.2")
        try:
            value = json.loads(text, parse_constant=_non_finite_constant)
        except ValueError as exc:  # json.JSONDecodeError is a ValueError too
            if is_int_digits_error(exc):
                raise ConfigError(f"--set {brief(pair)}: {key} is {int_digits_message()}") from None
            if not isinstance(exc, json.JSONDecodeError) or text.strip().lower().lstrip("+-") in _NON_FINITE:
                raise ConfigError(f"--set {brief(pair)}: {key} must be a finite number") from None
            value = text
        if not _all_finite(value):
            raise ConfigError(f"--set {brief(pair)}: {key} must be a finite number")
        settings[key] = value
    return settings


_NON_FINITE = ("nan", "inf", "infinity")


def _non_finite_constant(name: str) -> Any:
    raise ValueError(f"non-finite number {name}")


def _all_finite(value: Any) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, list):
        return all(_all_finite(v) for v in value)
    if isinstance(value, dict):
        return all(_all_finite(v) for v in value.values())
    return True


SEARCH_GROUPS = tuple(f.name for f in dataclasses.fields(SearchConfig))
"""The top-level groups of :class:`SearchConfig`; a setting key starting otherwise is a world key."""


def search_key(key: str) -> str:
    """The full dotted :class:`SearchConfig` key of a setting key: ``world.``, ``candidates.``,
    ``paths.`` and ``decisions.`` keys as they are, any other key (``robot.radius_m``,
    ``targets.count``, ``max_steps``) under ``world.``; ``__`` reads as ``.``. Not checked."""
    dotted = key.replace("__", ".")
    return dotted if dotted.split(".", 1)[0] in SEARCH_GROUPS else f"world.{dotted}"


def search_settings(settings: Mapping[str, Any]) -> dict[str, Any]:
    """Settings of the search world by their full keys (:func:`search_key`), sorted, with integers
    given to float fields as floats: the one form of a set of ``--set`` options (for a run's
    ``config.json`` and for worker processes). ConfigError names an unknown key, or a key that is a
    group of settings, and lists the keys known there."""
    out: dict[str, Any] = {}
    for key, value in settings.items():
        full = search_key(key)
        declared = _setting_field(full, key).type  # a string: this module's annotations are postponed
        if "float" in str(declared) and isinstance(value, int) and not isinstance(value, bool):
            if abs(value) > sys.float_info.max:  # float() would raise OverflowError
                raise ConfigError(f"setting {brief(key)} must be a finite number, got an integer beyond the floats")
            value = float(value)
        out[full] = value
    return dict(sorted(out.items()))


def search_config(settings: Mapping[str, Any] | None = None, base: SearchConfig | None = None) -> SearchConfig:
    """``base`` (default: :class:`SearchConfig`) with ``settings`` applied (:func:`search_settings`
    keys), validated. ConfigError names the first unknown key or bad value."""
    return override(base or SearchConfig(), **search_settings(settings or {})).validate()


def _setting_field(full: str, key: str) -> dataclasses.Field[Any]:
    """The dataclass field of the setting at dotted path ``full``; ConfigError naming ``key`` if none."""
    node: Any = SearchConfig()
    found: dataclasses.Field[Any] | None = None
    shown: list[str] = []  # the path as the user writes it (world. left out)
    for i, part in enumerate(full.split(".")):
        if not dataclasses.is_dataclass(node):
            raise ConfigError(f"unknown setting {brief(key)}: {'.'.join(shown)} is a single setting, with no fields")
        fields = {f.name: f for f in dataclasses.fields(node)}
        if part not in fields:
            raise ConfigError(f"unknown setting {brief(key)}; known settings: {_known(node, shown)}")
        found, node = fields[part], getattr(node, part)
        if i > 0 or part != "world":
            shown.append(part)
    if dataclasses.is_dataclass(node):
        raise ConfigError(f"setting {brief(key)} is a group of settings; set one of its fields: {_known(node, shown)}")
    assert found is not None
    return found


def _known(node: Any, shown: list[str]) -> str:
    """The keys known in group ``node`` (at path ``shown``), groups as ``name.*``; at the world's level
    also the other groups of :class:`SearchConfig`."""
    prefix = "".join(f"{part}." for part in shown)
    names = [
        f"{prefix}{f.name}.*" if dataclasses.is_dataclass(getattr(node, f.name)) else f"{prefix}{f.name}"
        for f in dataclasses.fields(node)
    ]
    if isinstance(node, WorldConfig):
        names += [f"{group}.*" for group in SEARCH_GROUPS if group != "world"]
    return ", ".join(names)


ConfigT = TypeVar("ConfigT", WorldConfig, SearchConfig)

_SEARCH_ONLY_GROUPS = tuple(group for group in SEARCH_GROUPS if group != "world")


def env_config(base: ConfigT, num_robots: int, keywords: Mapping[str, Any]) -> ConfigT:
    """The validated configuration of an environment built with ``num_robots`` robots and the keyword
    arguments ``keywords`` over ``base``: the one conversion of the environments' keyword forms
    (``protocol="passby"``, ``max_steps=400``, ``camera__width_px=96``, ``**{"camera.width_px": 96}``).

    ``base`` a :class:`WorldConfig` (the PettingZoo environment): every keyword is a world field.
    ``base`` a :class:`SearchConfig` (the Gymnasium goal environment): keywords starting with
    ``candidates``, ``paths`` or ``decisions`` reach those groups, every other one the world.
    ConfigError names an unknown key or a bad value."""
    if isinstance(base, WorldConfig):
        return override(base, num_robots=num_robots, **keywords).validate()
    world: dict[str, Any] = {}
    search: dict[str, Any] = {}
    for key, value in keywords.items():
        group = key.replace("__", ".").split(".", 1)[0]
        (search if group in _SEARCH_ONLY_GROUPS else world)[key] = value
    return override(base, world=override(base.world, num_robots=num_robots, **world), **search).validate()
