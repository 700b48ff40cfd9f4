"""Following a path (areasearch.planning.paths.follow): FMM planning, descent, the heading heuristic, the
progress window along a path, the detour requests of the step kernel, the path buffer."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from areasearch.config import PathConfig
from areasearch.errors import ConfigError
from areasearch.planning.paths import ActionPlanner, descend, heading_action, plan_path
from areasearch.planning.paths.follow import _heading, _nearest_on_path
from areasearch.planning.paths.state import ROBOT
from areasearch.sim.world import Action, World


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


def test_descend_follows_the_field_to_its_zero_and_gives_up_on_inf() -> None:
    yy, xx = np.mgrid[0:10, 0:12]
    field = np.hypot(yy - 2, xx - 9).astype(np.float32)  # zero at (2, 9)
    path = descend(field, 8, 1, field.size)
    assert tuple(path[0]) == (8, 1) and tuple(path[-1]) == (2, 9)
    assert (np.diff(field[path[:, 0], path[:, 1]]) < 0).all()  # strictly downhill
    field[8, 1] = np.inf
    assert len(descend(field, 8, 1, field.size)) == 0


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
    # the step kernel's own copy of the heuristic agrees
    assert _heading(0.0, 0.0, yaw, target[0], target[1], math.radians(5)) == expected


def test_the_nearest_path_cell_is_sought_within_the_progress_window() -> None:
    paths = np.zeros((1, 100, 2), dtype=np.int64)
    paths[0, :, 1] = np.arange(100)  # a straight path along row 0
    assert _nearest_on_path(paths, 0, 100, 0, 0, 50, 60) == 50
    assert _nearest_on_path(paths, 0, 100, 0, 0, 50, 40) == 39  # the window ends before the robot
    assert _nearest_on_path(paths, 0, 100, 30, 0, 10, 40) == 30  # progress never goes back
    assert _nearest_on_path(paths, 0, 45, 30, 0, 80, 40) == 44  # nor past the path's end


@pytest.mark.parametrize(
    ("every", "detours", "give_ways"),
    [(5, [3, 8, 13, 18], [8, 13, 18]), (3, [3, 6, 9, 12, 15, 18], [6, 9, 12, 15, 18])],
)
def test_a_robot_blocked_by_a_team_mate_seeks_a_detour_every_detour_every_steps(
    monkeypatch: pytest.MonkeyPatch,
    every: int,
    detours: list[int],
    give_ways: list[int],
    room_world: Callable[..., World],
) -> None:
    world = room_world()
    world.poses[0] = (1.0, 1.5, 0.0)
    world._sense()
    config = PathConfig(detour_every_steps=every)  # robot_wait_steps 2: the first detour at the 3rd try
    planner = ActionPlanner(config, world)
    planner.set_goals(world.scene.world_to_cell(np.array([[2.0, 1.5]])))
    asked: dict[str, list[int]] = {"detour": [], "give_way": []}

    def replan(r: int, cells: np.ndarray, avoid_robots: bool) -> Any:
        if avoid_robots:
            asked["detour"].append(int(planner.follower.waits[r]))
        return real_replan(r, cells, avoid_robots)

    def give_way(r: int, cells: np.ndarray, blocked_by: np.ndarray) -> Any:
        asked["give_way"].append(int(planner.follower.waits[r]))
        return real_give_way(r, cells, blocked_by)

    real_replan, real_give_way = planner.follower.replan, planner.give_way.blocked
    monkeypatch.setattr(planner.follower, "replan", replan)
    monkeypatch.setattr(planner.give_way, "blocked", give_way)
    for _ in range(18):  # blocked by a team-mate every step (the world is not stepped)
        planner.act(np.array([ROBOT], dtype=np.int8))
    assert asked == {"detour": detours, "give_way": give_ways}
    assert not planner.unreachable[0]  # 18 tries: below robot_wait_limit


def test_a_path_longer_than_the_path_buffer_grows_it_and_changes_nothing(room_world: Callable[..., World]) -> None:
    trails = {}
    for cells in (256, 8):
        world = room_world()
        world.poses[0] = (1.0, 0.8, 0.0)
        world._sense()
        planner = ActionPlanner(PathConfig(path_buffer_cells=cells), world)
        planner.set_goals(world.scene.world_to_cell(np.array([[4.0, 0.8]])))
        blocked = np.zeros(1, dtype=np.int8)
        trail = []
        for _ in range(60):
            blocked = world.step(planner.act(blocked)).blocked_by
            trail.append(world.poses[0].copy())
        path = planner.paths[0]
        assert path is not None and len(path) > 8
        assert planner.follower.buffer_cells >= len(path)
        trails[cells] = np.array(trail)
    np.testing.assert_array_equal(trails[8], trails[256])


@pytest.mark.parametrize(
    ("field", "bad"),
    [
        ("detour_every_steps", 0),
        ("detour_every_steps", 2.5),
        ("progress_window_cells", 0),
        ("progress_window_cells", True),
        ("path_buffer_cells", 0),
        ("path_buffer_cells", "256"),
    ],
)
def test_path_following_settings_are_validated(field: str, bad: object) -> None:
    with pytest.raises(ConfigError, match=re.escape(f"paths.{field} must be an integer >= 1")):
        PathConfig(**{field: bad}).validate()  # type: ignore[arg-type]
    PathConfig(**{field: 1}).validate()  # type: ignore[arg-type]
