"""The FMM action planner as a whole: arrival, no goal, unreachable goals. Its parts are tested in
test_paths_follow.py, test_paths_bumps.py, test_paths_give_way.py and test_paths_primitives.py."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from areasearch.config import PathConfig
from areasearch.planning.paths import ActionPlanner
from areasearch.sim.world import Action, World


def drive(world: World, planner: ActionPlanner, steps: int) -> np.ndarray:
    blocked = np.zeros(world.config.num_robots, dtype=np.int8)
    for _ in range(steps):
        blocked = world.step(planner.act(blocked)).blocked_by
    return blocked


def test_robot_reaches_its_goal_round_the_wall_and_stays(room_world: Callable[..., World]) -> None:
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


def test_no_goal_means_stay(room_world: Callable[..., World]) -> None:
    world = room_world()
    planner = ActionPlanner(PathConfig(), world)
    planner.set_goals(np.array([[-1, -1]]))
    assert planner.act(np.zeros(1, dtype=np.int8)).tolist() == [int(Action.STAY)]


def test_unreachable_goal_is_reported_and_the_robot_stays(room_world: Callable[..., World]) -> None:
    world = room_world()
    planner = ActionPlanner(PathConfig(), world)
    goal = np.array([[0, 0]])  # the sealed corner of the grid: an obstacle cell
    world.mapper.explored[:] = True  # the whole map known: no way through unknown space either
    world.mapper.occupied[:] = ~world.scene.free
    planner.set_goals(goal)
    actions = planner.act(np.zeros(1, dtype=np.int8))
    assert planner.unreachable[0] and actions[0] == int(Action.STAY)
