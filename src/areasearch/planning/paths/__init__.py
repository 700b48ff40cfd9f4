"""Pipeline stage "paths": the FMM action planner (DA-HGNN "Action Planner and Execution", after NCM).

Every robot follows its long-term goal with the planner of Ye et al. (CVPR 2022) that DA-HGNN
reuses: the shortest path from the robot to the goal by the Fast Marching Method on the current map
(known obstacles inflated by the footprint, unknown cells traversable), sub-sampled into waypoints;
the short-term goal is the waypoint ``lookahead_m`` ahead along the path, and the heading heuristic
of Chen et al. (2021) turns it into a primitive action: FORWARD when the robot faces the short-term
goal (within half a turn step), otherwise TURN_LEFT / TURN_RIGHT towards it.

Behaviour that users of frontier explorers asked for in their issue trackers: a goal that proves
unreachable or is blocked by a newly seen obstacle must not stall a robot or end the search (robots
of ROS explore_lite turning in place or stuck on unreachable frontiers, hrnr/m-explore issues #40
and #52; one failed goal aborting all exploration, paulbovbel/frontier_exploration pull request #25):

* **first path**: at a decision the path to the new goal is read off the robot's distance field that
  candidate extraction computed anyway (:class:`~areasearch.planning.candidates.Routes`), so a new goal
  costs no extra FMM;
* **re-planning**: a robot re-plans after it bumps into something and when the mapper marks an
  obstacle within a footprint of the next ``check_ahead_m`` of its path that was not on the map when
  the path was planned (``Mapper.occupied_at``; an old obstacle the path was planned beside is no
  reason to re-plan), by FMM from the goal that stops once it reaches the robot, first in a window
  around the robot and its goal, then over the whole planning window;
* **blocked by a robot**: a robot blocked by a team-mate waits (STAY) ``robot_wait_steps`` steps
  for it to pass, then re-plans treating the other robots' footprints as obstacles and goes round
  them (a detour is sought every ``detour_every_steps``-th blocked try); if they block every way it
  keeps waiting, and after ``robot_wait_limit`` blocked tries without moving the goal counts as
  unreachable (so the caller sends the robot elsewhere instead of leaving two robots face to face in
  a corridor);
* **arrived**: within ``goal_tolerance_m`` of its goal a robot turns to face the nearest frontier
  cell within ``look_radius_m`` of the goal (so a frontier is looked at, not only reached) and then
  stays (STAY, :attr:`ActionPlanner.settled`) until it gets a new goal: it never wanders off before
  the next decision;
* **bumped**: a FORWARD blocked by an obstacle the robot has not mapped (beside or behind its 90°
  view) marks the cells its centre would have crossed as impassable for planning (a collision map,
  as in Chaplot et al. 2020, :attr:`ActionPlanner.bumps`) for ``bump_memory_steps`` steps, and it
  re-plans; after ``max_bumps`` such bumps without moving the goal counts as unreachable. The
  high-level environment plans the candidates' distances round the same collision map, so a goal
  it offers is one the planner can reach;
* **unreachable**: when no path exists the robot stays and :attr:`ActionPlanner.unreachable` says so;
  the caller (the high-level environment) then gives it another goal;
* **giving way** (not in the paper): when a robot's detour round a blocking team-mate has not helped
  ``detour_every_steps`` steps later, the team-mate, if it has no goal, drives to the nearest cell
  off the other's way; if both block each other, the one of higher index does so, waits there, then
  (``give_way_steps`` after it began) goes on (:class:`~areasearch.planning.paths.give_way.GiveWay`). Without
  it, two robots that need one narrow passage in opposite ways could block each other for the rest
  of an episode;
* **primitive search** (not in the paper): a FORWARD that would bump into a mapped obstacle (by the
  world's own rule: the footprint swept along the move overlaps an obstacle cell,
  :mod:`areasearch.sim.footprint`) is replaced by a plan of primitive moves, A* over the poses FORWARD
  and the turns reach (:func:`primitive_search`), on the space the map shows free, to the goal if it
  lies within ``primitive_search_m``, else to the path that far ahead; searched first without the
  team-mates, and with them only when they are in the way. Without it, the heading heuristic could
  not enter a way in barely wider than the robot (it cut the corner and bumped, and its bump marks
  closed the way in on the planning grid). After a search that found no plan the robot does not
  search again for ``primitive_search_pause_steps`` steps.

Speed: everything a step needs for all robots (bump marks, arrival and look-around, waits, path
following with the check ahead and the line-of-sight short-term goal, the heading heuristic) is one
numba kernel call; only re-plans return to Python, and those build the planning grid of their window
alone (:func:`~areasearch.planning.window.window_grid`) and run the FMM and the descent in one kernel.

Paths are (N, 2) cell arrays from the robot's cell to the goal cell; distances in metres.

The parts, one module each, each holding its own state: :mod:`~areasearch.planning.paths.follow` (the
:class:`~areasearch.planning.paths.follow.Follower`: the paths, the step kernel, the heading heuristic, the
re-plans), :mod:`.planning` (the FMM path and the descent), :mod:`.bumps`
(the collision map: marking, expiry, the bump log), :mod:`~areasearch.planning.paths.give_way` (robots giving
way to each other), :mod:`~areasearch.planning.paths.jams` (holding for team-mates, the deadlock detector),
:mod:`~areasearch.planning.paths.primitives` (the primitive search and the approach points),
:mod:`~areasearch.planning.paths.context` (the read-only settings and world the parts share, and the goals),
:mod:`~areasearch.planning.paths.state` (the kernels' array layout) and :mod:`~areasearch.planning.paths.planner`
(:class:`ActionPlanner`, which makes the parts and calls them each step). The planner imports the
parts; no part imports the planner.
"""

from __future__ import annotations

from .follow import heading_action
from .planner import ActionPlanner
from .planning import descend, plan_path, route_path
from .primitives import primitive_search

__all__ = ["ActionPlanner", "descend", "heading_action", "plan_path", "primitive_search", "route_path"]
