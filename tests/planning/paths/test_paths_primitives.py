"""Primitive search (areasearch.planning.paths.primitives): the world's FORWARD rule, the bump-ahead check,
the A* over primitive moves, the approach points and the pause after a search that found nothing."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from areasearch.config import PathConfig, TargetConfig, WorldConfig
from areasearch.errors import ConfigError
from areasearch.planning.grid import Box
from areasearch.planning.paths import ActionPlanner, primitive_search
from areasearch.planning.paths.primitives import (
    MAX_MOVES,
    _forward_clear,
    _segment_distance,
    bumps_ahead,
)
from areasearch.planning.paths.state import FORWARD, STAY
from areasearch.sim.scene import scene_from_grid
from areasearch.sim.world import World


def slot_world() -> World:
    """A room with a dead-end slot 0.45 m wide in its north wall (the robot is 0.36 m across), the
    whole map known."""
    free = np.zeros((64, 84), dtype=bool)
    free[2:40, 2:82] = True
    free[40:60, 36:45] = True  # the slot: 9 cells (0.45 m) wide, 1 m deep
    world = World(WorldConfig(num_robots=1, targets=TargetConfig(count=1)))
    world.reset(scene_from_grid("slot", free, 0.05), np.random.default_rng(0))
    world.mapper.explored[:] = True
    world.mapper.occupied[:] = ~world.scene.free
    return world


def drive(world: World, planner: ActionPlanner, steps: int) -> np.ndarray:
    blocked = np.zeros(world.config.num_robots, dtype=np.int8)
    for _ in range(steps):
        blocked = world.step(planner.act(blocked)).blocked_by
    return blocked


@pytest.mark.parametrize(
    ("a", "b", "p", "expected"),
    [
        ((0.0, 0.0), (1.0, 0.0), (0.5, 0.3), 0.3),  # beside the segment
        ((0.0, 0.0), (1.0, 0.0), (1.3, 0.4), 0.5),  # past its end
        ((0.0, 0.0), (1.0, 0.0), (-0.3, 0.0), 0.3),  # before its start
        ((0.2, 0.2), (0.2, 0.2), (0.5, 0.6), 0.5),  # a point
    ],
)
def test_segment_distance(
    a: tuple[float, float], b: tuple[float, float], p: tuple[float, float], expected: float
) -> None:
    assert _segment_distance(*a, *b, *p) == pytest.approx(expected)


def test_forward_clear_follows_the_worlds_rule() -> None:
    obstacles = np.zeros((30, 30), dtype=bool)
    none = np.zeros((0, 2))
    r = 0.18
    assert _forward_clear(obstacles, 0, 0, 0.0, 0.0, 0.05, 0.6, 0.6, 0.0, 0.25, r, none, 0.0)
    obstacles[12, 20] = True  # a cell the footprint would sweep over (its square starts 1.0 m east)
    assert not _forward_clear(obstacles, 0, 0, 0.0, 0.0, 0.05, 0.6, 0.6, 0.0, 0.25, r, none, 0.0)
    assert _forward_clear(obstacles, 0, 0, 0.0, 0.0, 0.05, 0.6, 0.6, 0.0, 0.2, r, none, 0.0)  # stops 0.02 m short
    assert _forward_clear(obstacles, 0, 0, 0.0, 0.0, 0.05, 0.6, 0.6, math.pi / 2, 0.25, r, none, 0.0)
    assert not _forward_clear(obstacles, 0, 0, 0.0, 0.0, 0.05, 0.6, 0.6, math.pi, 0.45, r, none, 0.0)  # off the window
    other = np.array([[0.6, 1.05]])  # a team-mate 0.2 m from the end pose
    assert not _forward_clear(obstacles, 0, 0, 0.0, 0.0, 0.05, 0.6, 0.6, math.pi / 2, 0.25, r, other, 0.36**2)
    assert _forward_clear(obstacles, 0, 0, 0.0, 0.0, 0.05, 0.6, 0.6, math.pi / 2, 0.25, r, other, 0.1**2)


def testbumps_ahead_flags_a_forward_into_a_mapped_obstacle() -> None:
    world = slot_world()
    planner = ActionPlanner(PathConfig(), world)
    poses = np.array([[1.0, 0.35, -math.pi / 2], [1.0, 1.0, -math.pi / 2], [1.5, 0.35, -math.pi / 2]])
    actions = np.array([FORWARD, FORWARD, STAY])  # robot 0 towards the south wall, 1 in the open, 2 not moving
    out = np.zeros(3, dtype=np.bool_)
    none, failed = np.zeros(3, dtype=np.int64), np.full(3, -(10**9), dtype=np.int64)

    def check(moves_len: np.ndarray, moves_failed: np.ndarray) -> bool:
        occupied, radius = world.mapper.occupied, planner.context.radius_m
        return bumps_ahead(occupied, radius, 0.0, 0.0, 0.05, poses, actions, 0.25, moves_len, moves_failed, -1, out)

    assert check(none, failed) and out.tolist() == [True, False, False]
    assert not check(none, np.array([0, -(10**9), -(10**9)])) and not out.any()  # robot 0's last search failed
    assert check(np.array([0, 3, 0]), np.array([0, -(10**9), -(10**9)])) and not out.any()  # robot 1 has a plan


@pytest.mark.parametrize(
    "pose",
    [
        (1.2, 1.4, 0.0),  # south-west of the slot's mouth
        (1.2, 1.4, 2.0),
        (1.99, 1.93, 0.524),  # at the mouth, off the slot's axis
    ],
)
def test_a_primitive_plan_replays_in_the_world_without_a_blocked_move(pose: tuple[float, float, float]) -> None:
    world = slot_world()
    world.poses[0] = pose
    planner = ActionPlanner(PathConfig(), world)
    goal_xy = (2.025, 2.6)  # 0.6 m into the slot
    out = np.zeros(MAX_MOVES, dtype=np.int64)
    robot = world.config.robot
    h, w = world.scene.shape
    obstacles, (y0, x0) = planner.primitives.known_obstacles(Box(0, h, 0, w), 0)
    length = primitive_search(
        obstacles, y0, x0, *world.scene.origin_xy, 0.05, world.poses[0].copy(), robot.forward_m, robot.turn_rad,
        robot.radius_m, np.zeros((0, 2)), 0.0, *goal_xy, 0.1, False, 20000, out,
    )  # fmt: skip
    assert length > 0
    for action in out[:length]:
        assert not world.step(np.array([action])).collided.any()  # the world lets every move pass
    assert np.hypot(*(world.poses[0, :2] - goal_xy)) <= 0.1


def test_a_primitive_search_for_a_walled_off_goal_finds_none() -> None:
    world = slot_world()
    world.poses[0] = (1.2, 1.4, 0.0)
    planner = ActionPlanner(PathConfig(), world)
    h, w = world.scene.shape
    out = np.zeros(MAX_MOVES, dtype=np.int64)
    obstacles, (y0, x0) = planner.primitives.known_obstacles(Box(0, h, 0, w), 0)
    length = primitive_search(
        obstacles, y0, x0, *world.scene.origin_xy, 0.05, world.poses[0].copy(), 0.25, world.config.robot.turn_rad,
        0.18, np.zeros((0, 2)), 0.0, 3.0, 3.05, 0.1, False, 5000, out,
    )  # fmt: skip
    assert length == -1  # (3.0, 3.05) is inside the wall east of the slot


def test_known_obstacles_are_mapped_obstacles_and_unknown_cells_but_under_the_robot() -> None:
    world = slot_world()
    world.poses[0] = (1.0, 1.0, 0.0)
    planner = ActionPlanner(PathConfig(), world)
    h, w = world.scene.shape
    whole, origin = planner.primitives.known_obstacles(Box(0, h, 0, w), 0)
    assert origin == (0, 0)
    assert np.array_equal(whole, ~world.scene.free)
    world.mapper.explored[15:25, 15:25] = False  # under the robot (cell 20, 20) and round it
    whole, _ = planner.primitives.known_obstacles(Box(0, h, 0, w), 0)
    assert not whole[20, 20] and not whole[20, 23] and whole[15, 15] and whole[24, 24]
    part, (y0, x0) = planner.primitives.known_obstacles(Box(10, 30, 5, 40), 0)
    pad = int(np.abs(planner.context.offsets).max()) + 1
    assert (y0, x0) == (10 - pad, 5 - pad)
    np.testing.assert_array_equal(part, whole[y0 : y0 + part.shape[0], x0 : x0 + part.shape[1]])


@pytest.mark.parametrize("pose", [(3.2, 1.75, 3.0), (1.2, 1.4, 0.0)])
def test_a_robot_gets_into_the_slot_without_bumping_and_without_the_search_it_bumps(
    pose: tuple[float, float, float],
) -> None:
    bumps = {}
    for reach in (1.0, 0.0):
        world = slot_world()
        world.poses[0] = pose
        planner = ActionPlanner(PathConfig(primitive_search_m=reach), world)
        planner.set_goals(world.scene.world_to_cell(np.array([[2.025, 2.6]])), np.array([0.1]))
        drive(world, planner, 200)
        bumps[reach] = int(world.metrics.collisions[0])
        if reach > 0:
            assert planner.reached[0]
    assert bumps[1.0] == 0
    assert bumps[0.0] > 0


def approaching(pause: int) -> tuple[World, ActionPlanner]:
    """A robot 0.3 m short of a point it must drive over."""
    world = slot_world()
    world.poses[0] = (1.2, 1.4, 0.0)
    world.previous_xy[0] = (1.2, 1.4)  # it has not moved
    planner = ActionPlanner(PathConfig(primitive_search_pause_steps=pause), world)
    planner.set_goals(world.scene.world_to_cell(np.array([[1.5, 1.4]])), approach_xy=np.array([[1.5, 1.4]]))
    return world, planner


@pytest.mark.parametrize("pause", [0, 5, 40])
def test_a_search_is_not_due_again_for_primitive_search_pause_steps(pause: int) -> None:
    world, planner = approaching(pause)
    now = world.metrics.steps
    assert planner.primitives.approach_due(now)
    planner.primitives.failed_at[0] = now - pause + 1  # a search found no plan too recently
    assert not planner.primitives.approach_due(now)
    planner.primitives.failed_at[0] = now - pause
    assert planner.primitives.approach_due(now)
    planner.primitives.passed[0] = True
    assert not planner.primitives.approach_due(now)


def test_a_robot_with_a_point_to_drive_over_arrives_once_it_has() -> None:
    world, planner = approaching(40)
    tolerances = planner.primitives.arrival_tolerances()
    assert tolerances[0] == -1.0  # not before, however close
    world.previous_xy[0] = (1.4, 1.43)
    world.poses[0, :2] = (1.65, 1.43)  # the last move swept the robot's centre 3 cm from the point
    assert planner.primitives.arrival_tolerances()[0] == np.inf and planner.primitives.passed[0]
    planner.set_goals(planner.goals)  # no approach points: the plain tolerances
    assert planner.primitives.arrival_tolerances() is planner.tolerances_m


def test_primitive_search_settings_are_validated() -> None:
    with pytest.raises(ConfigError, match="primitive_search_m"):
        PathConfig(primitive_search_m=-1.0).validate()
    with pytest.raises(ConfigError, match="primitive_search_expansions"):
        PathConfig(primitive_search_expansions=0).validate()
    with pytest.raises(ConfigError, match=re.escape("paths.primitive_search_pause_steps must be an integer >= 0")):
        PathConfig(primitive_search_pause_steps=-1).validate()
    with pytest.raises(ConfigError, match="primitive_search_pause_steps"):
        PathConfig(primitive_search_pause_steps=2.5).validate()  # type: ignore[arg-type]
    PathConfig(primitive_search_pause_steps=0).validate()
