"""Pipeline stage "actions": primitive actions for each robot.

One reactive low-level controller, :func:`bounce_walk`, a seeded random walk that drives
forward and turns away after bumping into something: a sanity floor and the driver of the quick
start before goal planners exist.
"""

from __future__ import annotations

import numpy as np

from .world import Action


def bounce_walk(collided: np.ndarray, turning: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One action per robot: forward, except after a collision, when the robot turns one way for a
    random number of steps (kept in ``turning``, (R,) ints, updated in place: >0 left, <0 right)."""
    actions = np.full(len(collided), int(Action.FORWARD), dtype=np.int64)
    for r in np.flatnonzero(collided & (turning == 0)):
        turning[r] = int(rng.integers(3, 18)) * (1 if rng.random() < 0.5 else -1)
    for r in np.flatnonzero(turning != 0):
        actions[r] = int(Action.TURN_LEFT if turning[r] > 0 else Action.TURN_RIGHT)
        turning[r] -= int(np.sign(turning[r]))
    wiggle = (turning == 0) & (rng.random(len(collided)) < 0.05)
    actions[wiggle] = np.where(rng.random(int(wiggle.sum())) < 0.5, int(Action.TURN_LEFT), int(Action.TURN_RIGHT))
    return actions
