"""Goals for a team on your own map: the public import path of :mod:`areasearch.service.assign`.

``from areasearch.assign import assign_goals`` is what the README and docs/own-map.md use; the code
lives in the service floor (:mod:`areasearch.service`).
"""

from __future__ import annotations

from .service.assign import (
    Assignment,
    Assignments,
    DroppedTarget,
    OccupancyMap,
    assign_goals,
    build_decision,
    dumps,
    load_occupancy,
    occupancy_from_array,
    read_robots,
    read_targets,
    save_occupancy_yaml,
)

__all__ = [
    "Assignment",
    "Assignments",
    "DroppedTarget",
    "OccupancyMap",
    "assign_goals",
    "build_decision",
    "dumps",
    "load_occupancy",
    "occupancy_from_array",
    "read_robots",
    "read_targets",
    "save_occupancy_yaml",
]
