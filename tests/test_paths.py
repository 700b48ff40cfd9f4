"""The FMM action planner: paths, heading heuristic, arrival, bumps, unreachable goals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from areasearch.config import PathConfig, TargetConfig, WorldConfig
from areasearch.paths import ActionPlanner, heading_action, plan_path
from areasearch.scene import scene_from_grid
from areasearch.world import Action, World


def test_plan_path_goes_round_a_wall() -> None:
    passable = np.ones((30, 30), dtype=bool)
    passable[0:25, 15] = False  # a wall with a gap at the top
    path = plan_path(passable, np.array([2, 5]), np.array([2, 25]), 0.05)
    assert tuple(path[0]) == (2, 5) and tuple(path[-1]) == (2, 25)
    assert passable[path[:, 0], path[:, 1]].all()
    assert (np.abs(np.diff(path, axis=0)) <= 1).all()  # 8-connected steps
    assert path[:, 0].max() >= 25  # went through the gap
    passable[25:, 15] = False
    assert len(plan_path(passable, np.array([2, 5]), np.array([2, 25]), 0.05)) == 0


def test_plan_path_in_the_open_is_nearly_straight() -> None:
    passable = np.ones((40, 60), dtype=bool)
    path = plan_path(passable, np.array([20, 5]), np.array([20, 55]), 0.05)
    assert len(path) == 51
    assert np.abs(path[:, 0] - 20).max() <= 1


@pytest.mark.parametrize(
    ("yaw", "target", "expected"),
    [
        (0.0, (1.0, 0.02), Action.FORWARD),
        (0.0, (0.0, 1.0), Action.TURN_LEFT),
        (0.0, (0.0, -1.0), Action.TURN_RIGHT),
        (math.pi / 2, (-1.0, 0.0), Action.TURN_LEFT),
        (math.pi, (1.0, 0.1), Action.TURN_RIGHT),
    ],
)
def test_heading_heuristic(yaw: float, target: tuple[float, float], expected: Action) -> None:
    assert heading_action(np.array([0.0, 0.0, yaw]), np.array(target), math.radians(5)) == expected


def room_world(num_robots: int = 1) -> World:
    free = np.zeros((64, 104), dtype=bool)
    free[2:62, 2:102] = True
    free[2:50, 50:53] = False  # an inner wall; the way round is at the north end
    world = World(WorldConfig(num_robots=num_robots, targets=TargetConfig(count=5)))
    world.reset(scene_from_grid("room", free, 0.05), np.random.default_rng(0))
    return world


def drive(world: World, planner: ActionPlanner, steps: int) -> np.ndarray:
    blocked = np.zeros(world.config.num_robots, dtype=np.int8)
    for _ in range(steps):
        blocked = world.step(planner.act(blocked)).blocked_by
    return blocked


def test_robot_reaches_its_goal_round_the_wall_and_stays() -> None:
    world = room_world()
    world.poses[0] = (1.0, 0.8, 0.0)
    world._sense()
    planner = ActionPlanner(PathConfig(), world)
    goal = world.scene.world_to_cell(np.array([4.0, 0.8]))
    planner.set_goals(goal[None])
    drive(world, planner, 250)
    assert np.hypot(*(world.poses[0, :2] - (4.0, 0.8))) <= 0.25 + 1e-9
    assert planner.reached[0]
    here = world.poses[0, :2].copy()
    drive(world, planner, 40)
    np.testing.assert_array_equal(world.poses[0, :2], here)  # arrived: no wandering off
    assert world.metrics.collisions[0] <= 3


def test_no_goal_means_stay() -> None:
    world = room_world()
    planner = ActionPlanner(PathConfig(), world)
    planner.set_goals(np.array([[-1, -1]]))
    assert planner.act(np.zeros(1, dtype=np.int8)).tolist() == [int(Action.STAY)]


def test_unreachable_goal_is_reported_and_the_robot_stays() -> None:
    world = room_world()
    planner = ActionPlanner(PathConfig(), world)
    goal = np.array([[0, 0]])  # the sealed corner of the grid: an obstacle cell
    world.mapper.explored[:] = True  # the whole map known: no way through unknown space either
    world.mapper.occupied[:] = ~world.scene.free
    planner.set_goals(goal)
    actions = planner.act(np.zeros(1, dtype=np.int8))
    assert planner.unreachable[0] and actions[0] == int(Action.STAY)


def test_a_bump_marks_the_cells_ahead_and_triggers_a_replan() -> None:
    world = room_world()
    world.poses[0] = (2.3, 1.5, 0.0)  # facing the inner wall at x = 2.5 m, not yet mapped as seen
    planner = ActionPlanner(PathConfig(), world)
    planner.set_goals(world.scene.world_to_cell(np.array([[4.0, 1.5]])))
    before = planner.replans
    planner.act(np.array([1], dtype=np.int8))  # BLOCKED_BY_OBSTACLE
    assert planner._bumps.any()
    assert planner.replans > before


def test_two_robots_swap_sides_without_overlapping() -> None:
    world = room_world(num_robots=2)
    world.poses[0] = (0.5, 1.5, 0.0)  # head to head in the open half of the room
    world.poses[1] = (2.0, 1.5, math.pi)
    world._sense()
    planner = ActionPlanner(PathConfig(), world)
    goals = world.scene.world_to_cell(np.array([[2.0, 1.5], [0.5, 1.5]]))
    planner.set_goals(goals)
    blocked = np.zeros(2, dtype=np.int8)
    for _ in range(300):
        blocked = world.step(planner.act(blocked)).blocked_by
        assert np.hypot(*(world.poses[0, :2] - world.poses[1, :2])) >= 0.36
    assert planner.reached.all()
