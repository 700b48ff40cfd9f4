"""The layout the action planner's parts share: action codes, the columns of the per-robot state
array, what a robot needs from Python after the step kernel, and the slots of the kernels' float and
integer parameter arrays (:meth:`~areasearch.planning.paths.context.PlannerContext.build` fills them).

Plain integers, so that the numba kernels of every module read them as compile-time constants."""

from __future__ import annotations

from ...sim.world import BLOCKED_BY_OBSTACLE, BLOCKED_BY_ROBOT, Action

FORWARD, TURN_LEFT, TURN_RIGHT, STAY = (
    int(Action.FORWARD),
    int(Action.TURN_LEFT),
    int(Action.TURN_RIGHT),
    int(Action.STAY),
)
OBSTACLE, ROBOT = BLOCKED_BY_OBSTACLE, BLOCKED_BY_ROBOT
"""``StepResult.blocked_by`` codes: an obstacle, a team-mate."""
REPLAN, DETOUR = 1, 2
"""What a robot needs from Python after the step kernel (:meth:`~areasearch.planning.paths.follow.Follower.pending`)."""
PROGRESS, LENGTH, PLANNED, STUCK, WAITS, LAST = range(6)
"""Columns of the (R, 6) int64 state of :class:`~areasearch.planning.paths.follow.Follower`: path cell
nearest the robot, path length (0: no path), map version the path was planned on, bumps and
robot-blocked tries without moving, last action."""
F_OX, F_OY, F_CELL, F_TOL, F_VIEW, F_BUMP0, F_BUMP1, F_MIN_AIM = range(8)
"""Slots of :attr:`~areasearch.planning.paths.context.PlannerContext.fparams` (float64): map origin x, y
(metres) and cell size, the heading tolerance of a FORWARD and of looking at a frontier (radians),
the first and the last distance ahead a bump marks (metres), ``min_aim_m`` of :class:`~areasearch.config.PathConfig`."""
(
    I_CHECK,
    I_LOOKAHEAD,
    I_LOOK,
    I_MAX_BUMPS,
    I_WAIT_LIMIT,
    I_WAIT_STEPS,
    I_BUMP_MEMORY,
    I_DETOUR_EVERY,
    I_PROGRESS_WINDOW,
) = range(9)
"""Slots of :attr:`~areasearch.planning.paths.context.PlannerContext.iparams` (int64): the check ahead,
the lookahead and the look radius (cells), then ``max_bumps``, ``robot_wait_limit``,
``robot_wait_steps``, ``bump_memory_steps``, ``detour_every_steps`` and ``progress_window_cells``
of :class:`~areasearch.config.PathConfig`."""
