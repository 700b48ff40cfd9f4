"""What a goal call answers: one :class:`Assignment` per robot, the targets no robot can take
(:class:`DroppedTarget`), and their JSON as ``areasearch assign`` prints it and the service answers it
(:func:`assignments_json`, :func:`dumps`: byte for byte the same text from both).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..inputs import short
from ..planning.candidates import CandidateKind
from .decision import Decision
from .grid import OccupancyMap

KINDS = {int(CandidateKind.FRONTIER): "frontier", int(CandidateKind.TARGET): "target"}
"""Goal type names by :class:`~areasearch.planning.candidates.CandidateKind`; ``"none"``: no goal."""


@dataclass(frozen=True)
class Assignment:
    """One robot's goal, in the map frame."""

    robot: int
    """Index of the robot in the poses given."""
    kind: str
    """``"frontier"`` (explore there), ``"target"`` (cover that target) or ``"none"`` (no reachable goal)."""
    goal_xy: tuple[float, float] | None
    """Goal position (x, y), metres (the centre of the goal cell); None when ``kind == "none"``."""
    target: int | None
    """Index of the target in the targets given, for a target goal."""
    distance_m: float | None
    """Geodesic (FMM) length of the way to the goal, metres."""
    path_xy: list[tuple[float, float]]
    """Planned path from the robot's position to the goal, (x, y) metres, a point about every
    ``path_step_m`` (the last point is the goal); empty without a goal."""

    def to_json(self) -> dict[str, Any]:
        return {
            "goal": None if self.goal_xy is None else [round(v, 4) for v in self.goal_xy],
            "type": self.kind,
            "target": self.target,
            "distance_m": None if self.distance_m is None else round(self.distance_m, 4),
            "path": [[round(x, 4), round(y, 4)] for x, y in self.path_xy],
        }


@dataclass(frozen=True)
class DroppedTarget:
    """A target given that no robot can take as its goal."""

    target: int
    """Index of the target in the targets given."""
    xy: tuple[float, float]
    """Its position (x, y), metres."""
    reason: str
    """Why: ``"in a wall"`` (an occupied cell), ``"in unknown space"``, ``"unreachable"`` (each with no
    free cell a robot reaches within the snap distance), or ``"over the candidate limit"``
    (``candidates.max_candidates`` nearer candidates were kept)."""

    def to_json(self) -> dict[str, Any]:
        return {"x": round(self.xy[0], 4), "y": round(self.xy[1], 4), "reason": self.reason}


class Assignments(list[Assignment]):
    """The list of :func:`assign_goals`: one :class:`Assignment` per robot, and the targets given that
    cannot be a goal of any robot (:attr:`dropped_targets`)."""

    dropped_targets: list[DroppedTarget]

    def __init__(self, assignments: Sequence[Assignment] = (), dropped: Sequence[DroppedTarget] = ()) -> None:
        super().__init__(assignments)
        self.dropped_targets = list(dropped)


def dropped_targets(decision: Decision, grid: OccupancyMap, targets_xy: np.ndarray) -> list[DroppedTarget]:
    """The targets (``targets_xy``, as given to :func:`build_decision`) that no robot may take as its
    goal in ``decision``, each with the reason: where its cell lies, or the candidate limit."""
    cand = decision.candidates
    allowed = np.asarray(decision.obs["action_mask"][:, : len(cand)], dtype=bool).any(axis=0).reshape(-1)
    goal = {
        int(t): bool(ok)
        for t, ok, k in zip(cand.target_id, allowed, cand.kind, strict=True)
        if k == CandidateKind.TARGET
    }
    out = []
    cells = grid.world_to_cell(targets_xy) if len(targets_xy) else np.zeros((0, 2), dtype=np.int64)
    for t, (iy, ix) in enumerate(cells):
        if goal.get(t, False):
            continue
        if t not in goal:
            reason = "over the candidate limit"
        elif grid.occupied[iy, ix]:
            reason = "in a wall"
        elif not grid.free[iy, ix]:
            reason = "in unknown space"
        else:
            reason = "unreachable"
        out.append(DroppedTarget(t, (float(targets_xy[t, 0]), float(targets_xy[t, 1])), reason))
    return out


_PAIR = re.compile(r"\[\s*(-?[0-9][0-9.eE+-]*),\s*(-?[0-9][0-9.eE+-]*)\s*\]")


def dumps(doc: Any) -> str:
    """``doc`` as indented JSON with every [x, y] pair of numbers on one line."""
    return _PAIR.sub(r"[\1, \2]", json.dumps(doc, indent=2)) + "\n"


def assignments_json(
    assignments: Sequence[Assignment],
    robot_ids: Sequence[str],
    target_ids: Sequence[str],
    method: str,
    weights: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """The JSON document ``areasearch assign`` prints: the method (and, for weights of your own,
    ``weights`` and ``weights_sha256``: :meth:`areasearch.planners.Choice.record`), one entry per
    robot and, when targets were given, ``dropped_targets``: those no robot can take as a goal, with
    the reason."""
    robots = []
    for a in assignments:
        entry = {"id": robot_ids[a.robot], **a.to_json()}
        if a.target is not None:
            entry["target"] = target_ids[a.target]
        robots.append(entry)
    doc: dict[str, Any] = {"frame": "map", "method": method, **(weights or {}), "robots": robots}
    if target_ids:
        dropped = getattr(assignments, "dropped_targets", [])
        doc["dropped_targets"] = [{"id": target_ids[d.target], **d.to_json()} for d in dropped]
    return doc


def dropped_lines(assignments: Sequence[Assignment], target_ids: Sequence[str]) -> list[str]:
    """One line per dropped target of ``assignments``, for stderr."""
    return [
        f"target {short(target_ids[d.target], 40)} at ({d.xy[0]:g}, {d.xy[1]:g}) cannot be a goal ({d.reason}); dropped"
        for d in getattr(assignments, "dropped_targets", [])
    ]
