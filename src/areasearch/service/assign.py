"""Goals for your own robots on your own map: the goal planners as one library call.

A robot team that already runs SLAM and localisation has an occupancy grid (a ROS ``map_server``
YAML, a PNG, or the ``nav_msgs/OccupancyGrid`` array) and the robots' poses in the map frame.
:func:`assign_goals` turns those into one long-term goal per robot, chosen by any registered goal
planner (classical or learned), with the planned path to it::

    from areasearch.service.assign import assign_goals

    for a in assign_goals("my_map.yaml", [(1.0, 2.0, 0.0), (1.5, 2.0, 3.14)], method="voronoi"):
        print(a.robot, a.kind, a.goal_xy, a.distance_m, len(a.path_xy))

The grid is a *partial* map, as a SLAM system produces it: known-free cells are explored, occupied
cells are obstacles, unknown cells are unexplored. Everything the planners see comes from that map,
never from a ground truth: the same pipeline stages as the simulator's decisions
(:func:`areasearch.planning.candidates.extract_candidates` for frontier and target nodes with FMM distances,
the observation of :class:`areasearch.envs.goal.AreaSearchEnv` (:func:`areasearch.envs.observation.build_observation`),
``planner.assign(obs)``, and the
path read off each robot's FMM distance field by steepest descent, as the action planner does).

Frames and units: poses are (x, y, yaw) in metres and radians in the map frame, whose ``origin``
(the map-frame position of the south-west corner of cell [0, 0]) is honoured; grids are indexed
``[iy, ix]`` with ``iy`` growing northwards (ROS: row 0 of ``OccupancyGrid.data`` is at the origin;
the image's bottom row). Goals and paths come back in the same frame, metres.

Rules for what a real map holds:

* a cell is free when its occupancy is below ``free_thresh``, occupied above ``occupied_thresh``,
  unknown otherwise (map_server's trinary reading; ``OccupancyGrid`` value -1 is unknown);
* unknown cells under a robot's footprint are free (the robot stands there; a fresh SLAM map often
  has not seen the floor under its own sensor), and so is an unknown pocket of at most 1 m² enclosed
  by known cells that a robot stands in (a sensor's blind spot around itself);
* a robot whose centre is nearer a wall than the planner's clearance (localisation noise, a tight
  spot) plans from the nearest free cell that has the clearance, if one lies within that clearance;
  its path starts at its own position;
* a robot centre on an occupied cell, outside the grid, non-finite, more than
  :data:`~areasearch.config.MAX_ROBOTS` robots, or two robots closer than the footprint's diameter
  (their footprints overlap), is an error (:class:`~areasearch.errors.ConfigError`), as is a map with no free
  cell or no free cell that can hold the footprint (:class:`~areasearch.errors.MapError`).

A robot gets ``kind == "none"`` (no goal, empty path) when no candidate is reachable for it: the
map is finished, or the robot is walled in. A yaw is any finite angle (normalised to [-pi, pi)). A
target that no robot can take as its goal (in a wall or in unknown space with no reachable cell
within the snap distance, unreachable, or over the candidate limit) is listed, with the reason, in
the returned list's ``dropped_targets`` (:class:`Assignments`).

The parts live beside this module: the map and its readers (:mod:`.grid`), the observation built
from it (:mod:`.decision`), the answer and its JSON (:mod:`.answer`), the robots and targets JSON
(:mod:`.team`); their public names are imported here too, so that ``areasearch.service.assign`` is
the one import path of the goal call (the command line, the public shim :mod:`areasearch.assign`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..config import SearchConfig, override
from ..errors import ConfigError
from ..inputs import real_number, short
from ..planners import GoalPlanner, choose_planner
from ..planning.candidates import CandidateKind
from ..planning.paths import route_path
from .answer import (
    KINDS,
    Assignment,
    Assignments,
    DroppedTarget,
    assignments_json,
    dropped_lines,
    dropped_targets,
    dumps,
)
from .decision import Decision, build_decision, finite_rows, normalise_yaw
from .grid import (
    FREE_THRESH,
    OCCUPIED_THRESH,
    OccupancyMap,
    as_occupancy,
    load_occupancy,
    occupancy_from_array,
    save_occupancy_yaml,
)
from .team import RobotsFile, read_robots, read_targets, robots_from_json, targets_from_json

__all__ = [
    "FREE_THRESH",
    "KINDS",
    "MAX_PATH_STEP_M",
    "OCCUPIED_THRESH",
    "Assignment",
    "Assignments",
    "Decision",
    "DroppedTarget",
    "OccupancyMap",
    "RobotsFile",
    "as_occupancy",
    "assign_goals",
    "assignments_json",
    "build_decision",
    "dropped_lines",
    "dropped_targets",
    "dumps",
    "load_occupancy",
    "normalise_yaw",
    "occupancy_from_array",
    "read_robots",
    "read_targets",
    "robots_from_json",
    "save_occupancy_yaml",
    "targets_from_json",
]

MAX_PATH_STEP_M = 100.0
"""Largest spacing of the points of a returned path, metres."""


def _path(
    decision: Decision, r: int, goal_cell: np.ndarray, start_xy: np.ndarray, step_m: float
) -> list[tuple[float, float]]:
    """Robot ``r``'s path to ``goal_cell`` read off its FMM field (as the action planner reads a first
    path, :func:`~areasearch.planning.paths.route_path`), sub-sampled every ``step_m``; from ``start_xy``."""
    routes = decision.candidates.routes
    grid = decision.grid
    assert routes is not None
    cells = route_path(routes, r, goal_cell - routes.box.origin) + routes.box.origin  # robot cell ... goal cell
    if len(cells) == 0:
        cells = goal_cell[None]
    every = max(1, round(step_m / grid.cell_m))
    keep = [*range(every, len(cells) - 1, every), len(cells) - 1]
    points = [(float(start_xy[0]), float(start_xy[1]))]
    points += [(float(x), float(y)) for x, y in grid.cell_to_world(cells[keep])]
    return points


def assign_goals(
    grid: OccupancyMap | str | Path | np.ndarray,
    poses: Any,
    method: str | GoalPlanner | None = None,
    targets: Any = None,
    past_positions: Sequence[Any] | None = None,
    past_goals: Sequence[Any] | None = None,
    *,
    resolution: float | None = None,
    origin: Sequence[float] | None = None,
    config: SearchConfig | None = None,
    radius_m: float | None = None,
    sensor_range_m: float | None = None,
    seed: int = 0,
    progress: float = 0.0,
    path_step_m: float = 0.25,
    planner_settings: dict[str, Any] | None = None,
    robot_names: Sequence[str] | None = None,
) -> Assignments:
    """One goal per robot on your own (partial) map; see the module docstring.

    Args:
        grid: a ROS map YAML path, a PNG / PGM path (with ``resolution``, optional ``origin``), an
            ``OccupancyGrid``-style array (-1 unknown, 0-100; with ``resolution``, optional
            ``origin`` [x, y] or [x, y, 0]), or an :class:`OccupancyMap`.
        poses: (R, 3) x, y, yaw of the robots: metres, radians, the map frame.
        method: a registered planner name (``areasearch.planners.PLANNERS``: ``greedy``,
            ``utility``, ``voronoi``, ``coscan``, ``hungarian``, ``random``, the learned ones, the
            plug-ins; ``areasearch methods`` lists them), a planner object (reused across calls, e.g.
            a network loaded once), or None: ``greedy``, or with ``planner_settings["weights"]`` the
            learned network those weights describe.
        targets: (T, 2) x, y of known targets to cover (e.g. detected people), or None.
        past_positions, past_goals: per robot, its positions / goals at its past decisions, newest
            first, as [x, y] (a goal may be None); the learned planners use them.
        config: the settings (footprint, sensor range, candidates); ``radius_m`` and
            ``sensor_range_m`` override its robot radius and camera range.
        seed: seed of the planner's generator (same inputs and seed, same goals).
        progress: share of the mission time spent, in [0, 1] (an input of the learned planners).
        path_step_m: spacing of the path points, metres.
        planner_settings: keyword settings of a named planner (e.g. ``{"weights": "runs/x/policy"}``:
            a learned planner plays those weights, ``PREFIX.safetensors`` + ``PREFIX.json``).
        robot_names: names of the robots for error messages (default: their index).

    Returns one :class:`Assignment` per robot, in the order of ``poses`` (an :class:`Assignments`
    list, whose ``dropped_targets`` are the targets that cannot be any robot's goal, with the
    reason). Raises ConfigError or MapError, with one message naming the input at fault, on bad input.
    """
    # the arguments are checked as the command line checks its options, each error naming the argument;
    # NumPy scalars are numbers (np.float32 from a ROS message), bools, complex numbers and text are not
    cfg, seed, path_step_m = _checked_settings(config, radius_m, sensor_range_m, seed, path_step_m)
    planner = _planner(method, planner_settings, robot_names)
    occupancy = as_occupancy(grid, resolution, origin)
    decision = build_decision(
        occupancy, poses, targets, past_positions, past_goals, config=cfg, progress=progress, robot_names=robot_names
    )
    targets_xy = finite_rows("targets", [] if targets is None else targets, 2, "x, y in metres")
    dropped = dropped_targets(decision, occupancy, targets_xy)
    planner.reset(np.random.default_rng(seed))
    choice = np.asarray(planner.assign(decision.obs)).reshape(-1)
    poses_xy = np.asarray(poses, dtype=np.float64).reshape(-1, 3)[:, :2]
    return Assignments(_goals(decision, occupancy, choice, poses_xy, path_step_m), dropped)


def _checked_settings(
    config: SearchConfig | None, radius_m: Any, sensor_range_m: Any, seed: Any, path_step_m: Any
) -> tuple[SearchConfig, int, float]:
    """The settings of :func:`assign_goals` (``radius_m`` and ``sensor_range_m`` applied), its seed and
    its path spacing, checked as the command line checks its options; ConfigError naming the argument."""
    cfg = config or SearchConfig()
    if not isinstance(cfg, SearchConfig):
        raise ConfigError(f"config must be an areasearch.config.SearchConfig, got {short(cfg)}")
    changes: dict[str, Any] = {}
    if radius_m is not None:
        changes["world.robot.radius_m"] = real_number("radius_m", radius_m)
    if sensor_range_m is not None:
        changes["world.camera.max_range_m"] = real_number("sensor_range_m", sensor_range_m)
    cfg = override(cfg, **changes).validate() if changes else cfg.validate()
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, (bool, np.bool_)) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {short(seed)}")
    step = real_number("path_step_m", path_step_m)
    if not 0 < step <= MAX_PATH_STEP_M:
        raise ConfigError(f"path_step_m must be a positive number of at most {MAX_PATH_STEP_M:g} m, got {step:g}")
    return cfg, int(seed), step


def _planner(method: str | GoalPlanner | None, planner_settings: Any, robot_names: Sequence[str] | None) -> GoalPlanner:
    """The planner of :func:`assign_goals`: ``method`` itself when it is a planner object, else the
    registered planner it names (with ``planner_settings``); ConfigError naming the argument at fault
    (``robot_names`` is checked here too, before the map is read)."""
    if planner_settings is not None and not isinstance(planner_settings, Mapping):
        raise ConfigError(f"planner_settings must be a mapping of keyword settings, got {short(planner_settings)}")
    if robot_names is not None and (isinstance(robot_names, str) or not all(isinstance(n, str) for n in robot_names)):
        raise ConfigError(f"robot_names must be a list of strings, one per robot, got {short(robot_names)}")
    if (
        method is not None
        and not isinstance(method, str)
        and not (callable(getattr(method, "assign", None)) and callable(getattr(method, "reset", None)))
    ):
        raise ConfigError(
            f"method must be a planner name or a GoalPlanner (with assign and reset), got {short(method)}"
        )
    if method is None or isinstance(method, str):
        settings = dict(planner_settings or {})
        return choose_planner(method, settings.pop("weights", None), **settings).planner
    return method


def _goals(
    decision: Decision, occupancy: OccupancyMap, choice: np.ndarray, poses_xy: np.ndarray, path_step_m: float
) -> list[Assignment]:
    """One :class:`Assignment` per robot from the planner's ``choice`` of candidates; a choice outside
    the planner's contract (no such candidate, or one not allowed) is replaced by the nearest allowed
    candidate, and a robot with none gets ``kind == "none"``."""
    cand = decision.candidates
    allowed = decision.obs["action_mask"][:, : len(cand)].astype(bool)
    out = []
    for r in range(len(poses_xy)):
        i = int(choice[r]) if r < len(choice) else -1
        if not (0 <= i < len(cand) and allowed[r, i]):  # a planner outside its contract: nearest allowed
            i = int(np.argmin(np.where(allowed[r], cand.distance_m[r], np.inf))) if allowed[r].any() else -1
        if i < 0:
            out.append(Assignment(r, "none", None, None, None, []))
            continue
        goal_xy = occupancy.cell_to_world(cand.cells[i])
        out.append(
            Assignment(
                robot=r,
                kind=KINDS[int(cand.kind[i])],
                goal_xy=(float(goal_xy[0]), float(goal_xy[1])),
                target=int(cand.target_id[i]) if cand.kind[i] == CandidateKind.TARGET else None,
                distance_m=float(cand.distance_m[r, i]),
                path_xy=_path(decision, r, cand.cells[i], poses_xy[r], path_step_m),
            )
        )
    return out
