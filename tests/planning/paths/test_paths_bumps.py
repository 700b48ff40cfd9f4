"""Bump memory (areasearch.planning.paths.bumps): marking the cells a blocked FORWARD would have crossed,
their expiry, the bump log and its growth, and the planner re-planning round the marks."""

from __future__ import annotations

import re
from collections.abc import Callable

import numpy as np
import pytest

from areasearch.config import PathConfig
from areasearch.errors import ConfigError
from areasearch.planning.paths import ActionPlanner
from areasearch.planning.paths.bumps import BUMP_SAMPLES, BumpMemory, expire_bumps, mark_bumps
from areasearch.planning.paths.state import F_BUMP0, F_BUMP1, F_CELL, I_BUMP_MEMORY, OBSTACLE, ROBOT
from areasearch.sim.world import World

CELL_M = 0.05


def params(memory_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """The kernels' parameter arrays for a map with origin (0, 0), 5 cm cells, a 25 cm FORWARD."""
    fparams = np.zeros(7)
    fparams[F_CELL], fparams[F_BUMP0], fparams[F_BUMP1] = CELL_M, CELL_M / 2, 0.25
    iparams = np.zeros(9, dtype=np.int64)
    iparams[I_BUMP_MEMORY] = memory_steps
    return fparams, iparams


def bump(memory: BumpMemory, poses: np.ndarray, blocked_by: np.ndarray, version: int, now: int, steps: int) -> None:
    """One step of the bump memory as the step kernel runs it."""
    fparams, iparams = params(steps)
    memory.make_room(len(poses))
    expire_bumps(now, memory.mask, memory.count, memory.at, memory.log, memory.ptr)
    mark_bumps(
        poses, blocked_by, version, now, fparams, iparams, memory.mask, memory.count, memory.at, memory.log, memory.ptr
    )


def test_a_bump_marks_the_cells_ahead_but_not_the_robots_own() -> None:
    memory = BumpMemory((20, 20), 2, 64)
    assert not memory.live
    poses = np.array([[0.5, 0.5, 0.0], [0.3, 0.3, 0.0]])  # robot 0 in cell (10, 10), facing +x
    bump(memory, poses, np.array([OBSTACLE, ROBOT], dtype=np.int8), version=7, now=3, steps=10)
    marked = np.argwhere(memory.mask)
    assert [tuple(c) for c in marked] == [(10, x) for x in range(11, 16)]  # 0.525 m ... 0.75 m ahead
    assert memory.live and memory.count.sum() == 5 and (memory.at[memory.mask] == 7).all()
    head, tail = memory.ptr
    assert (head, tail) == (0, 5)
    np.testing.assert_array_equal(memory.log[:5], [[13, 10, x] for x in range(11, 16)])  # expire at step 3 + 10


def test_marks_expire_after_bump_memory_steps_and_overlapping_marks_last_as_long_as_the_newest() -> None:
    memory = BumpMemory((20, 20), 1, 64)
    pose = np.array([[0.5, 0.5, 0.0]])
    blocked = np.array([OBSTACLE], dtype=np.int8)
    bump(memory, pose, blocked, version=2, now=0, steps=10)
    bump(memory, pose, blocked, version=4, now=5, steps=10)  # the same cells again
    assert memory.count.max() == 2 and (memory.at[memory.mask] == 4).all()
    idle = np.zeros(1, dtype=np.int8)
    bump(memory, pose, idle, version=6, now=9, steps=10)
    assert memory.count.max() == 2
    bump(memory, pose, idle, version=6, now=10, steps=10)  # the first bump's marks expire
    assert memory.mask.sum() == 5 and memory.count.max() == 1 and (memory.at[memory.mask] == 4).all()
    bump(memory, pose, idle, version=6, now=15, steps=10)
    assert not memory.mask.any() and not memory.count.any() and not memory.at.any() and not memory.live


def test_make_room_keeps_the_live_marks_in_order_and_doubles_a_full_log() -> None:
    memory = BumpMemory((20, 20), 1, 1)
    assert len(memory.log) == BUMP_SAMPLES
    memory.log[:4] = [[5, 1, 1], [6, 1, 2], [7, 1, 3], [8, 1, 4]]
    memory.ptr[:] = (1, 4)
    memory.make_room(1)  # 4 + 6 > 6: three live marks to the front, the log doubled until they fill at most half
    assert tuple(memory.ptr) == (0, 3) and len(memory.log) == 4 * BUMP_SAMPLES
    np.testing.assert_array_equal(memory.log[:3], [[6, 1, 2], [7, 1, 3], [8, 1, 4]])
    memory.make_room(1)  # room enough: nothing moves
    assert tuple(memory.ptr) == (0, 3) and len(memory.log) == 4 * BUMP_SAMPLES


def test_the_bump_log_size_changes_nothing_but_memory() -> None:
    rng = np.random.default_rng(3)
    small, large = BumpMemory((40, 40), 3, 1), BumpMemory((40, 40), 3, 64)
    for now in range(300):
        poses = np.column_stack([rng.uniform(0.2, 1.8, 3), rng.uniform(0.2, 1.8, 3), rng.uniform(-np.pi, np.pi, 3)])
        blocked = np.where(rng.random(3) < 0.4, OBSTACLE, 0).astype(np.int8)
        for memory in (small, large):
            bump(memory, poses, blocked, version=2 * now + 1, now=now, steps=25)
        for a, b in ((small.mask, large.mask), (small.count, large.count), (small.at, large.at)):
            np.testing.assert_array_equal(a, b)
    assert len(small.log) < len(large.log)


def test_a_bump_marks_the_cells_ahead_and_triggers_a_replan(room_world: Callable[..., World]) -> None:
    world = room_world()
    world.poses[0] = (2.3, 1.5, 0.0)  # facing the inner wall at x = 2.5 m, not yet mapped as seen
    planner = ActionPlanner(PathConfig(), world)
    planner.set_goals(world.scene.world_to_cell(np.array([[4.0, 1.5]])))
    before = planner.replans
    planner.act(np.array([1], dtype=np.int8))  # BLOCKED_BY_OBSTACLE
    assert planner.bumps.any()
    assert planner.replans > before


@pytest.mark.parametrize("bad", [0, -3, 1.5, None])
def test_the_bump_log_size_is_validated(bad: object) -> None:
    with pytest.raises(ConfigError, match=re.escape("paths.bump_log_per_robot must be an integer >= 1")):
        PathConfig(bump_log_per_robot=bad).validate()  # type: ignore[arg-type]
