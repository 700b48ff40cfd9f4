"""The FMM action planner: paths, heading heuristic, arrival, bumps, unreachable goals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from areasearch.config import PathConfig, TargetConfig, WorldConfig
from areasearch.errors import ConfigError
from areasearch.geodesic import Box
from areasearch.paths import ActionPlanner, _primitive_search, heading_action, plan_path
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


def slot_world() -> World:
    """A room with a dead-end slot 0.5 m wide in its north wall (the robot is 0.36 m across), the
    whole map known."""
    free = np.zeros((64, 84), dtype=bool)
    free[2:40, 2:82] = True
    free[40:60, 36:46] = True  # the slot: 10 cells (0.5 m) wide, 1 m deep
    world = World(WorldConfig(num_robots=1, targets=TargetConfig(count=1)))
    world.reset(scene_from_grid("slot", free, 0.05), np.random.default_rng(0))
    world.mapper.explored[:] = True
    world.mapper.occupied[:] = ~world.scene.free
    return world


@pytest.mark.parametrize(
    "pose",
    [
        (1.2, 1.4, 0.0),  # south-west of the slot's mouth
        (1.2, 1.4, 2.0),
        (1.967, 1.939, 0.524),  # in the mouth, off the slot's axis: out, round and back in (28 moves)
    ],
)
def test_a_primitive_plan_replays_in_the_world_without_a_blocked_move(pose: tuple[float, float, float]) -> None:
    world = slot_world()
    world.poses[0] = pose
    planner = ActionPlanner(PathConfig(), world)
    goal_xy = (2.05, 2.6)  # 0.6 m into the slot
    out = np.zeros(48, dtype=np.int64)
    robot = world.config.robot
    h, w = world.scene.shape
    length = _primitive_search(
        planner._known_blocked(Box(0, h, 0, w)), 0, 0, *world.scene.origin_xy, 0.05, world.poses[0].copy(),
        robot.forward_m, robot.turn_rad, np.zeros((0, 2)), 0.0, *goal_xy, 0.1, 20000, out,
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
    out = np.zeros(48, dtype=np.int64)
    length = _primitive_search(
        planner._known_blocked(Box(0, h, 0, w)), 0, 0, *world.scene.origin_xy, 0.05, world.poses[0].copy(),
        0.25, world.config.robot.turn_rad, np.zeros((0, 2)), 0.0, 3.0, 3.05, 0.1, 5000, out,
    )  # fmt: skip
    assert length == -1  # (3.0, 3.05) is inside the wall east of the slot


@pytest.mark.parametrize("pose", [(3.2, 1.75, 3.0), (0.5, 0.5, 0.0)])
def test_a_robot_gets_into_the_slot_without_bumping_and_without_the_search_it_bumps(
    pose: tuple[float, float, float],
) -> None:
    bumps = {}
    for reach in (1.0, 0.0):
        world = slot_world()
        world.poses[0] = pose
        planner = ActionPlanner(PathConfig(primitive_search_m=reach), world)
        planner.set_goals(world.scene.world_to_cell(np.array([[2.05, 2.6]])), np.array([0.1]))
        drive(world, planner, 200)
        bumps[reach] = int(world.metrics.collisions[0])
        if reach > 0:
            assert planner.reached[0]
    assert bumps[1.0] == 0
    assert bumps[0.0] > 0


def test_primitive_search_settings_are_validated() -> None:
    with pytest.raises(ConfigError, match="primitive_search_m"):
        PathConfig(primitive_search_m=-1.0).validate()
    with pytest.raises(ConfigError, match="primitive_search_expansions"):
        PathConfig(primitive_search_expansions=0).validate()
