"""Bump memory: the collision map (as in Chaplot et al. 2020).

A FORWARD blocked by an obstacle the robot has not mapped (beside or behind its 90° view) marks the
cells its centre would have crossed as impassable for planning (:func:`mark_bumps`), for
``bump_memory_steps`` steps (:func:`expire_bumps`). :class:`BumpMemory` holds the marks: the (H, W)
mask the planning grid and the candidates' distance fields are blocked by, a count of live marks per
cell (marks of several bumps may overlap), the map version of the newest mark of each cell (a path
planned before it is checked again), and the log of marks in the order they were made, so that they
expire in that order.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .state import F_BUMP0, F_BUMP1, F_CELL, F_OX, F_OY, I_BUMP_MEMORY, OBSTACLE

BUMP_SAMPLES = 6
"""Points along a blocked forward move whose cells a bump marks."""


class BumpMemory:
    """The collision map of one world's robots and the log its marks expire by.

    ``log`` (L, 3) int64 rows (expiry step, iy, ix) from ``ptr[0]`` (the oldest live mark) to
    ``ptr[1]`` (the end); the step kernel appends to it, :meth:`make_room` keeps room for one step of
    bumps of every robot. Its first size is ``per_robot`` bumps per robot
    (``PathConfig.bump_log_per_robot``); it doubles when fuller, so the size does not change behaviour."""

    def __init__(self, shape: tuple[int, int], num_robots: int, per_robot: int) -> None:
        self.mask = np.zeros(shape, dtype=bool)
        """(H, W) bool: cells a live mark covers, impassable for planning."""
        self.count = np.zeros(shape, dtype=np.int32)
        """(H, W) live marks per cell."""
        self.at = np.zeros(shape, dtype=np.int64)
        """(H, W) map version of the newest live mark of each cell (0: none)."""
        self.log = np.zeros((per_robot * BUMP_SAMPLES * num_robots, 3), dtype=np.int64)
        self.ptr = np.zeros(2, dtype=np.int64)

    @property
    def live(self) -> bool:
        """Some mark is live."""
        return bool(self.ptr[1] > self.ptr[0])

    def make_room(self, num_robots: int) -> None:
        """Make room in the log for a step of bumps of ``num_robots`` robots, if it has none: move the
        live marks to its front and double it while they would fill more than half of it."""
        if self.ptr[1] + BUMP_SAMPLES * num_robots <= len(self.log):
            return
        head, tail = (int(v) for v in self.ptr)
        live = self.log[head:tail].copy()
        size = len(self.log)
        while len(live) + BUMP_SAMPLES * num_robots > size // 2:
            size *= 2
        if size != len(self.log):
            self.log = np.zeros((size, 3), dtype=np.int64)
        self.log[: len(live)] = live
        self.ptr[:] = (0, len(live))


@numba.njit(cache=True, nogil=True)
def expire_bumps(
    now: int,
    bumps: np.ndarray,
    bump_count: np.ndarray,
    bumps_at: np.ndarray,
    bump_log: np.ndarray,
    bump_ptr: np.ndarray,
) -> None:
    """Drop the marks whose expiry step has come by step ``now`` (the arrays of a :class:`BumpMemory`)."""
    while bump_ptr[0] < bump_ptr[1] and bump_log[bump_ptr[0], 0] <= now:
        y, x = bump_log[bump_ptr[0], 1], bump_log[bump_ptr[0], 2]
        bump_ptr[0] += 1
        bump_count[y, x] -= 1
        if bump_count[y, x] == 0:
            bumps[y, x] = False
            bumps_at[y, x] = 0


@numba.njit(cache=True, nogil=True)
def mark_bumps(
    poses: np.ndarray,
    blocked_by: np.ndarray,
    version: int,
    now: int,
    fparams: np.ndarray,
    iparams: np.ndarray,
    bumps: np.ndarray,
    bump_count: np.ndarray,
    bumps_at: np.ndarray,
    bump_log: np.ndarray,
    bump_ptr: np.ndarray,
) -> None:
    """Mark the cells the centre of a robot whose FORWARD an obstacle blocked would have crossed
    (``BUMP_SAMPLES`` points from ``fparams[F_BUMP0]`` to ``fparams[F_BUMP1]`` ahead, the robot's own
    cell left out) with map version ``version``, expiring ``iparams[I_BUMP_MEMORY]`` steps after
    ``now``. The log needs room for ``BUMP_SAMPLES`` marks a robot (:meth:`BumpMemory.make_room`)."""
    n = poses.shape[0]
    gh, gw = bumps.shape
    ox, oy, cell_m = fparams[F_OX], fparams[F_OY], fparams[F_CELL]
    for r in range(n):
        if blocked_by[r] != OBSTACLE:
            continue
        px, py = poses[r, 0], poses[r, 1]
        hy = int(math.floor((py - oy) / cell_m))
        hx = int(math.floor((px - ox) / cell_m))
        c, s = math.cos(poses[r, 2]), math.sin(poses[r, 2])
        d0, d1 = fparams[F_BUMP0], fparams[F_BUMP1]
        for k in range(BUMP_SAMPLES):
            d = d1 if k == BUMP_SAMPLES - 1 else d0 + k * (d1 - d0) / (BUMP_SAMPLES - 1)
            y = int(math.floor((py + d * s - oy) / cell_m))
            x = int(math.floor((px + d * c - ox) / cell_m))
            if (y == hy and x == hx) or y < 0 or x < 0 or y >= gh or x >= gw:
                continue
            bumps[y, x] = True
            bump_count[y, x] += 1
            bumps_at[y, x] = version
            t = bump_ptr[1]
            bump_log[t, 0] = now + iparams[I_BUMP_MEMORY]
            bump_log[t, 1] = y
            bump_log[t, 2] = x
            bump_ptr[1] = t + 1
