"""Giving way (areasearch.planning.paths.give_way.GiveWay): the team-mate in the way, the spot off the other's way,
who gives way when two block each other, and the end of giving way after give_way_steps."""

from __future__ import annotations

import math
import re
from collections.abc import Callable

import numpy as np
import pytest

from areasearch.config import PathConfig
from areasearch.errors import ConfigError
from areasearch.planning.paths import ActionPlanner
from areasearch.planning.paths.state import ROBOT, STAY
from areasearch.sim.world import World

CELL_M = 0.05
HeadToHead = Callable[..., tuple[World, ActionPlanner, np.ndarray]]


@pytest.fixture
def head_to_head(room_world: Callable[..., World]) -> HeadToHead:
    """A function that places two robots face to face 0.4 m apart, robot 0 heading east to (2.0, 1.5)."""

    def make(config: PathConfig | None = None, goal_of_1: bool = True) -> tuple[World, ActionPlanner, np.ndarray]:
        world = room_world(2, known=True)
        world.poses[0] = (1.0, 1.5, 0.0)
        world.poses[1] = (1.4, 1.5, math.pi)
        planner = ActionPlanner(config or PathConfig(), world)
        goals = world.scene.world_to_cell(np.array([[2.0, 1.5], [0.4, 1.5]]))
        if not goal_of_1:
            goals[1] = -1
        planner.set_goals(goals)
        return world, planner, world.scene.world_to_cell(world.poses[:, :2])

    return make


@pytest.mark.parametrize(("x", "expected"), [(1.4, 1), (2.0, -1), (0.7, -1)])
def test_the_blocker_is_the_team_mate_a_forward_would_run_into(
    x: float, expected: int, room_world: Callable[..., World]
) -> None:
    world = room_world(2)
    world.poses[0] = (1.0, 1.5, 0.0)
    world.poses[1] = (x, 1.5, math.pi)
    assert ActionPlanner(PathConfig(), world).give_way.blocker(0) == expected


def test_an_idle_team_mate_in_the_way_is_sent_off_the_way(
    head_to_head: HeadToHead,
) -> None:
    _, planner, cells = head_to_head(goal_of_1=False)
    assert planner.follower.replan(0, cells, avoid_robots=False)  # robot 0 has a path through robot 1
    ahead = planner.follower.path_ahead(0)
    assert not planner.give_way.blocked(0, cells, np.array([ROBOT, 0], dtype=np.int8))  # robot 0 itself waits
    spot = planner.goals[1]
    assert spot[0] >= 0 and planner.tolerances_m[1] == CELL_M and not planner.reached[1]
    path = planner.paths[1]
    assert path is not None and tuple(path[0]) == tuple(cells[1]) and tuple(path[-1]) == tuple(spot)
    # off robot 0's next move (a footprint and a step round it) and off the footprints along its way
    assert np.hypot(*(spot - cells[0])) > (2 * 0.18 + 0.25) / CELL_M
    assert np.hypot(*(ahead - spot).T).min() > 2 * 0.18 / CELL_M


def test_of_two_robots_blocking_each_other_the_higher_index_gives_way(
    head_to_head: HeadToHead,
) -> None:
    world, planner, cells = head_to_head()
    both = np.array([ROBOT, ROBOT], dtype=np.int8)
    assert not planner.give_way.blocked(0, cells, both)
    assert not planner.give_way.blocked(1, cells, np.array([0, ROBOT], dtype=np.int8))  # robot 0 is not blocked
    assert len(planner.give_way.robots()) == 0
    assert planner.give_way.blocked(1, cells, both)
    spot = planner.give_way.spot(1)
    assert spot[0] >= 0 and planner.give_way.steps(1) == 0
    path = planner.paths[1]
    assert path is not None and tuple(path[-1]) == tuple(spot)
    assert (planner.goals[1] == world.scene.world_to_cell(np.array([0.4, 1.5]))).all()  # its goal is kept


@pytest.mark.parametrize("steps", [3, 40])
def test_a_robot_gives_way_for_give_way_steps_then_replans_to_its_goal(steps: int, head_to_head: HeadToHead) -> None:
    _, planner, cells = head_to_head(PathConfig(give_way_steps=steps))
    assert planner.give_way.blocked(1, cells, np.array([ROBOT, ROBOT], dtype=np.int8))
    planner.follower.waits[1] = 5
    actions = np.full(2, -1, dtype=np.int64)
    for _ in range(steps):
        planner.give_way.carry_on(1, cells, actions)
        assert planner.give_way.active(1) and planner.follower.has_path(1)
    assert actions[1] == -1  # on its way to the spot, the step kernel's action stands
    planner.give_way.carry_on(1, cells, actions)
    assert not planner.give_way.active(1)
    assert not planner.follower.has_path(1) and planner.follower.waits[1] == 0  # re-plans on the next step


def test_a_robot_at_its_spot_stays(head_to_head: HeadToHead) -> None:
    _, planner, cells = head_to_head()
    assert planner.give_way.blocked(1, cells, np.array([ROBOT, ROBOT], dtype=np.int8))
    there = cells.copy()
    there[1] = planner.give_way.spot(1)
    actions = np.full(2, -1, dtype=np.int64)
    planner.give_way.carry_on(1, there, actions)
    assert actions[1] == STAY and planner.give_way.active(1)


def test_two_robots_swap_sides_without_overlapping(room_world: Callable[..., World]) -> None:
    world = room_world(2)
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


@pytest.mark.parametrize("bad", [0, -1, 2.0])
def test_give_way_steps_is_validated(bad: object) -> None:
    with pytest.raises(ConfigError, match=re.escape("paths.give_way_steps must be an integer >= 1")):
        PathConfig(give_way_steps=bad).validate()  # type: ignore[arg-type]
