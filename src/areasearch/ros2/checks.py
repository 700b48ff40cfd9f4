"""Bad messages the ROS 2 node meets, each named by its cause and logged once (:class:`Problems`).

A robot stack sends what it has: an empty map before SLAM has scanned, a map of unknown cells only,
a NaN pose from a diverged filter, a robot that localisation puts off the map or in a wall, a map in
another frame than the poses. The node never plans on such data and never stops for it: the map is
not used (the last good one stays), the robot is left out of the decision until a good pose comes,
the targets message is ignored. Messages come many times a second, so each cause is logged once per
subject (a robot, ``/map``, the targets), with what the node does instead; :attr:`Problems.counts`
keeps how often each was met.

Pure functions on :mod:`.convert`'s values: nothing here imports rclpy.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import MapError
from ..service.grid import OccupancyMap
from .convert import RobotPose, grid_from_message

LEFT_OUT = "the robot is left out of the decisions until a good pose arrives"
MAP_UNUSED = "the map is not used (the last good map, if any, stays)"
TARGETS_IGNORED = "the targets message is ignored (the last good targets stay)"
TARGET_LEFT_OUT = "the target is left out of the decisions"
NO_GOALS = "no goal is published from this decision"


@dataclass(frozen=True)
class Problem:
    """One bad input: why (``cause``), whose (``subject``), and the message naming it."""

    cause: str
    """A short name of the cause (``pose not finite``, ``off the map``...), the key it is logged once by."""
    subject: str
    """What it is about: a robot's namespace, ``/map``, ``/areasearch/targets``, ``decision``."""
    message: str


def _pattern(text: str) -> str:
    """``text`` with its numbers replaced by ``#``: one cause for "robot at (1.2, 3) ..." and "(1.3, 3) ..."."""
    return re.sub(r"-?\d+(\.\d+)?(e[+-]?\d+)?", "#", text)


class Problems:
    """The bad inputs met so far: each (cause, subject) logged once, by ``log``, with what the node does."""

    def __init__(self, log: Callable[[str], Any], note: Callable[[str], Any] | None = None) -> None:
        self.log = log
        """Where a problem's line goes (the node's logger, warning level)."""
        self.note = note or log
        """Where a notice (waiting for a first message) goes (the node's logger, info level)."""
        self.counts: Counter[tuple[str, str]] = Counter()
        """How often each (cause, subject) was met."""
        self.logged: list[str] = []
        """The lines logged, in order."""

    def report(self, problem: Problem, then: str) -> None:
        """Count ``problem``; log it, with ``then`` (what the node does instead), the first time its cause is met."""
        key = (problem.cause, problem.subject)
        self.counts[key] += 1
        if self.counts[key] == 1:
            line = f"{problem.subject}: {problem.message}; {then} (logged once)"
            self.logged.append(line)
            self.log(line)

    def notice(self, key: str, line: str) -> None:
        """Log ``line`` once per ``key`` (not a bad input: e.g. no map has come yet)."""
        if self.counts[("notice", key)] == 0:
            self.logged.append(line)
            self.note(line)
        self.counts[("notice", key)] += 1


def read_map(msg: Any, source: str = "/map") -> OccupancyMap | Problem:
    """The map of an ``OccupancyGrid`` message, or the :class:`Problem` that makes it unusable: an
    ``empty map`` (no cell), an ``all-unknown map`` (nothing known, nothing to plan on), or an
    ``unusable map`` (the library's MapError: sizes that do not match, values outside -1..100, a
    tilted or rotated origin, no free cell)."""
    try:
        return grid_from_message(msg, source)
    except MapError as err:
        values = np.asarray(msg.data)
        cells = int(msg.info.width) * int(msg.info.height)
        if cells == 0 or values.size == 0:
            return Problem("empty map", source, str(err).removeprefix(f"{source}: "))
        if values.size == cells and values.dtype.kind in "iu" and bool((values == -1).all()):
            return Problem("all-unknown map", source, "every cell is unknown (-1): nothing to plan on")
        text = str(err).removeprefix(f"{source}: ")
        return Problem(f"unusable map: {_pattern(text)}", source, text)


def pose_problem(
    pose: RobotPose, name: str, grid: OccupancyMap | None = None, map_frame: str | None = None
) -> Problem | None:
    """What makes robot ``name``'s ``pose`` unusable, None when nothing does: a value that is not
    finite; with the map, a frame other than the map's, a position off the map or on an occupied
    cell (in a wall)."""
    if not (math.isfinite(pose.x) and math.isfinite(pose.y) and math.isfinite(pose.yaw)):
        return Problem(
            "pose not finite",
            name,
            f"pose ({pose.x:g}, {pose.y:g}, yaw {pose.yaw:g}) is not finite (or its quaternion)",
        )
    if grid is None:
        return None
    if map_frame is not None and pose.frame != map_frame:
        return Problem(
            "frame",
            name,
            f"pose in frame {pose.frame!r}, the map in {map_frame!r}; poses and the map must share a frame",
        )
    xy = np.array([[pose.x, pose.y]])
    if not grid.contains(xy)[0]:
        return Problem("off the map", name, f"at ({pose.x:g}, {pose.y:g}), off the map ({grid.bounds_text()})")
    iy, ix = grid.world_to_cell(xy)[0]
    if grid.occupied[iy, ix]:
        return Problem("in a wall", name, f"at ({pose.x:g}, {pose.y:g}), on an occupied cell of the map (in a wall)")
    return None


TARGETS = "/areasearch/targets"


def targets_problem(xy: np.ndarray) -> Problem | None:
    """A targets message whose positions are not all finite."""
    bad = ~np.isfinite(xy).all(axis=1)
    if bad.any():
        t = int(np.flatnonzero(bad)[0])
        return Problem("targets not finite", TARGETS, f"target {t} at {xy[t].tolist()} is not finite")
    return None


def usable_targets(
    xy: np.ndarray, frame: str, grid: OccupancyMap, map_frame: str
) -> tuple[np.ndarray, list[int], list[Problem]]:
    """The targets a decision takes: all of them when their frame is the map's (none otherwise),
    less those off the map; their indices in the message; the problems met."""
    if len(xy) == 0:
        return xy.reshape(0, 2), [], []
    if frame != map_frame:
        text = f"targets in frame {frame!r}, the map in {map_frame!r}; they must share a frame"
        return np.zeros((0, 2)), [], [Problem("frame", TARGETS, text)]
    on_map = grid.contains(xy)
    problems = [
        Problem("target off the map", TARGETS, f"target {t} at ({xy[t, 0]:g}, {xy[t, 1]:g}) lies off the map")
        for t in np.flatnonzero(~on_map)
    ]
    kept = np.flatnonzero(on_map)
    return xy[kept], [int(t) for t in kept], problems


def refused(err: Exception) -> Problem:
    """A decision the goal call refused (two robots overlapping, no room for a footprint...): one cause
    per kind of message."""
    text = " ".join(str(err).split())
    return Problem(f"refused: {_pattern(text)}", "decision", text)
