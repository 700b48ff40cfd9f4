"""The robots and targets JSON of ``areasearch assign`` (``robots.json``, ``targets.json``, ``--robots -``)
and of the goal service's requests: read and checked by one set of functions, so that the command line
and the service refuse the same lists with the same words (each message starting with its source: the
file, ``standard input`` or ``request``).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..config import MAX_ROBOTS
from ..errors import ConfigError
from ..inputs import LIMIT_VARIABLES, clip, limits, parse_json, read_bytes, short


def _json_file(path: str | Path, what: str, keys: Sequence[str]) -> dict[str, Any]:
    """The JSON object of a ``what`` file (at most :attr:`~areasearch.inputs.InputLimits.max_json_bytes`)
    whose top-level keys are ``keys``, the first required; ConfigError naming the file otherwise."""
    path = Path(path).expanduser()
    data = read_bytes(path, f"{what} file", limits().max_json_bytes, LIMIT_VARIABLES["max_json_bytes"], ConfigError)
    return _json_doc(data, str(path), keys)


def _json_doc(data: bytes, path: str, keys: Sequence[str]) -> dict[str, Any]:
    """The JSON object in ``data`` (read from ``path``, named in the messages) whose top-level keys are
    ``keys``, the first required; ConfigError otherwise."""
    doc = parse_json(data, path, ConfigError)  # an integer of over 4,300 digits too: one message
    if not isinstance(doc, dict) or not isinstance(doc.get(keys[0]), list):
        raise ConfigError(f"{path}: expected an object with a {keys[0]!r} list")
    unknown = sorted(set(doc) - set(keys))
    if unknown:
        raise ConfigError(
            f"{path}: unknown top-level field(s) {', '.join(short(k, 30) for k in unknown[:5])}"
            f"{' ...' if len(unknown) > 5 else ''}; known: {', '.join(keys)}"
        )
    return doc


def _number(source: str, name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{source}: {name} must be a number, got {short(value)}")
    try:
        number = float(value)
    except OverflowError:  # an integer beyond the largest float
        raise ConfigError(f"{source}: {name} must be a finite number, got {short(value)}") from None
    if not math.isfinite(number):
        raise ConfigError(f"{source}: {name} must be a finite number, got {value!r}")
    return number


def _point(source: str, name: str, value: Any) -> list[float]:
    if not isinstance(value, list) or len(value) != 2:
        raise ConfigError(f"{source}: {name} must be an [x, y] pair of numbers, got {short(value)}")
    return [_number(source, f"{name}[{k}]", v) for k, v in enumerate(value)]


_ROBOT_FIELDS = frozenset({"id", "x", "y", "yaw", "past_positions", "past_goals"})
_TARGET_FIELDS = frozenset({"id", "x", "y"})


def _object_xy(source: str, name: str, item: Any, shape: str, fields: frozenset[str]) -> tuple[float, float]:
    """The x, y of list entry ``name``, which must be an object with ``shape`` and no field beyond ``fields``."""
    if not isinstance(item, dict):
        raise ConfigError(f"{source}: {name} must be an object with {shape}, got {short(item)}")
    unknown = sorted(set(item) - fields)
    if unknown:
        raise ConfigError(f"{source}: {name} has unknown field(s) {', '.join(short(k, 30) for k in unknown[:5])}")
    xy = []
    for key in ("x", "y"):
        if key not in item:
            raise ConfigError(f"{source}: {name} has no {key!r}")
        xy.append(_number(source, f"{name}.{key}", item[key]))
    return xy[0], xy[1]


def _ids(source: str, name: str, items: list[Any], prefix: str) -> list[str]:
    ids = []
    for k, item in enumerate(items):
        value = item.get("id", f"{prefix}_{k}")
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{source}: {name}[{k}].id must be a non-empty string, got {short(value)}")
        ids.append(value)
    if len(set(ids)) != len(ids):
        seen: set[str] = set()
        dup = ids[0]
        for dup in ids:
            if dup in seen:
                break
            seen.add(dup)
        raise ConfigError(f"{source}: {name} id {short(dup)} is used twice")
    return ids


@dataclass(frozen=True)
class RobotsFile:
    """The contents of a robots JSON file (see :func:`read_robots`)."""

    ids: list[str]
    poses: np.ndarray
    """(R, 3) x, y, yaw."""
    past_positions: list[list[list[float]]] | None
    past_goals: list[list[list[float] | None]] | None


def read_robots(path: str | Path) -> RobotsFile:
    """Read a robots file: ``{"robots": [{"id": "tb3_0", "x": 1.0, "y": 2.0, "yaw": 0.0,
    "past_positions": [[x, y], ...], "past_goals": [[x, y] | null, ...]}, ...]}`` (``id``, ``yaw``
    (default 0) and the past lists (newest first) optional). ConfigError naming the entry at fault."""
    if str(path) == "-":  # `areasearch assign --robots -`: the robots JSON on standard input
        source = "standard input"
        return robots_from_json(_json_doc(_stdin_bytes("robots"), source, ("robots",))["robots"], source)
    return robots_from_json(_json_file(path, "robots", ("robots",))["robots"], str(path))


def _stdin_bytes(what: str) -> bytes:
    """The bytes of standard input, at most :attr:`~areasearch.inputs.InputLimits.max_json_bytes`
    (read one byte beyond, so a larger input is refused without being read whole)."""
    bound = limits().max_json_bytes
    if sys.stdin is None or sys.stdin.isatty():
        raise ConfigError(f"standard input is a terminal; pipe the {what} JSON in (... | areasearch assign --robots -)")
    try:
        data = sys.stdin.buffer.read(bound + 1)
    except (OSError, ValueError, AttributeError) as exc:  # closed or not a byte stream
        raise ConfigError(f"standard input: cannot read the {what} JSON ({clip(str(exc))})") from None
    if len(data) > bound:
        raise ConfigError(
            f"standard input: the {what} JSON is larger than {bound:,} bytes, the limit "
            f"(environment variable {LIMIT_VARIABLES['max_json_bytes']})"
        )
    return data


def robots_from_json(items: list[Any], source: str) -> RobotsFile:
    """The robots of a parsed robots JSON (the ``"robots"`` list of :func:`read_robots`), with its
    checks and messages, each starting with ``source`` (the file, or the request of the goal service)."""
    if not isinstance(items, list):
        raise ConfigError(f"{source}: 'robots' must be a list of robots, got {short(items)}")
    if not items:
        raise ConfigError(f"{source}: 'robots' is empty; give at least one robot")
    if len(items) > MAX_ROBOTS:
        raise ConfigError(f"{source}: {len(items)} robots; the planners plan for at most {MAX_ROBOTS}")
    poses = np.zeros((len(items), 3))
    pasts: list[list[list[float]]] = []
    goals: list[list[list[float] | None]] = []
    has_past = has_goals = False
    for k, item in enumerate(items):
        name = f"robots[{k}]"
        poses[k, :2] = _object_xy(source, name, item, "x, y, yaw", _ROBOT_FIELDS)
        poses[k, 2] = _number(source, f"{name}.yaw", item.get("yaw", 0.0))
        past = item.get("past_positions", [])
        gone = item.get("past_goals", [])
        if not isinstance(past, list) or not isinstance(gone, list):
            raise ConfigError(f"{source}: {name}.past_positions and past_goals must be lists of [x, y]")
        has_past |= "past_positions" in item
        has_goals |= "past_goals" in item
        pasts.append([_point(source, f"{name}.past_positions[{i}]", p) for i, p in enumerate(past)])
        goals.append([None if g is None else _point(source, f"{name}.past_goals[{i}]", g) for i, g in enumerate(gone)])
    return RobotsFile(
        _ids(source, "robots", items, "robot"), poses, pasts if has_past else None, goals if has_goals else None
    )


def read_targets(path: str | Path) -> tuple[list[str], np.ndarray]:
    """Read a targets file: ``{"targets": [{"id": "person_1", "x": 3.0, "y": 1.5}, ...]}`` (``id``
    optional). Returns (ids, (T, 2) x, y)."""
    return targets_from_json(_json_file(path, "targets", ("targets",))["targets"], str(path))


def targets_from_json(items: list[Any], source: str) -> tuple[list[str], np.ndarray]:
    """The targets of a parsed targets JSON (the ``"targets"`` list of :func:`read_targets`), with its
    checks and messages, each starting with ``source``. Returns (ids, (T, 2) x, y)."""
    if not isinstance(items, list):
        raise ConfigError(f"{source}: 'targets' must be a list of targets, got {short(items)}")
    xy = np.zeros((len(items), 2))
    for k, item in enumerate(items):
        xy[k] = _object_xy(source, f"targets[{k}]", item, "x, y", _TARGET_FIELDS)
    return _ids(source, "targets", items, "target"), xy
