"""The doorway test geometry (``layouts.two_rooms``): widths, angles, thickness, jagged edges."""

from __future__ import annotations

import numpy as np
import pytest

from areasearch.goal_env import AreaSearchEnv, nearest_candidate
from areasearch.layouts import two_rooms
from areasearch.scene import scene_from_grid

ANGLES = (0.0, 15.0, 30.0, 45.0, 60.0)


@pytest.mark.parametrize("width", [0.40, 0.45, 0.90])
def test_a_straight_doorway_has_its_clear_width(width: float) -> None:
    rooms = two_rooms(width)
    column = rooms.free[:, rooms.free.shape[1] // 2]  # the wall's column
    assert column.sum() * rooms.cell_m == pytest.approx(width)
    assert np.ptp(np.flatnonzero(column)) + 1 == column.sum()  # one gap


@pytest.mark.parametrize("wall_m", [0.05, 0.2])
@pytest.mark.parametrize("jagged", [False, True])
@pytest.mark.parametrize("angle", ANGLES)
def test_the_wall_separates_the_rooms_but_for_the_doorway(angle: float, jagged: bool, wall_m: float) -> None:
    """Too narrow for the footprint (0.30 m < 0.36 m): the team's region is one room; wide (0.9 m):
    both, at every angle, thickness and edge."""
    for width, both in ((0.30, False), (0.90, True)):
        rooms = two_rooms(width, wall_angle_deg=angle, wall_m=wall_m, jagged=jagged)
        reachable = scene_from_grid("rooms", rooms.free, rooms.cell_m).reachable(0.18)
        sides = (reachable & rooms.far).any(), (reachable & ~rooms.far).any()
        assert (sides[0] and sides[1]) == both, (width, angle, jagged, wall_m)


def test_jagged_edges_follow_the_seed_and_a_thicker_wall_is_thicker() -> None:
    a = two_rooms(0.6, wall_angle_deg=20.0, jagged=True, seed=1).free
    assert np.array_equal(a, two_rooms(0.6, wall_angle_deg=20.0, jagged=True, seed=1).free)
    assert not np.array_equal(a, two_rooms(0.6, wall_angle_deg=20.0, jagged=True, seed=2).free)
    assert (~two_rooms(0.6, wall_m=0.2).free).sum() > (~two_rooms(0.6, wall_m=0.05).free).sum()


def test_bad_geometry_is_refused() -> None:
    with pytest.raises(ValueError, match="wall_angle_deg"):
        two_rooms(0.6, wall_angle_deg=75.0)
    with pytest.raises(ValueError, match="positive"):
        two_rooms(0.0)


@pytest.mark.slow
def test_a_robot_explores_through_a_wide_slanted_doorway() -> None:
    rooms = two_rooms(0.9, wall_angle_deg=30.0, wall_m=0.2)
    scene = scene_from_grid("rooms", rooms.free, rooms.cell_m)
    env = AreaSearchEnv(map=scene, num_robots=1, seed=0, max_steps=1200)
    obs, info = env.reset(seed=0)
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(nearest_candidate(obs))
        done = terminated or truncated
    cells = scene.world_to_cell(env.world.trajectory[: info["steps"] + 1, 0, :2])
    visited = rooms.far[cells[:, 0], cells[:, 1]]
    assert visited.any() and not visited.all()  # it was in both rooms
    assert info["explored_pct"] > 95.0


def test_start_poses_can_be_given_and_bad_ones_are_refused() -> None:
    import areasearch
    from areasearch.errors import ConfigError

    rooms = two_rooms(0.9)
    scene = scene_from_grid("rooms", rooms.free, rooms.cell_m)
    poses = [[1.0, 1.0, 0.0], [1.0, 2.0, 1.0]]
    env = AreaSearchEnv(map=scene, num_robots=2, seed=0, max_steps=80)
    env.reset(seed=0, options={"poses": poses})
    assert np.allclose(env.world.poses, poses)
    par = areasearch.parallel_env(map=scene, num_robots=2, seed=0, max_steps=80)
    par.reset(seed=0, options={"poses": poses})
    assert np.allclose(par.unwrapped.world.poses, poses)  # type: ignore[attr-defined]
    for bad, message in (
        ([[0.05, 0.05, 0.0], [1.0, 2.0, 0.0]], "robot 0 .* not where a robot can stand"),  # in the outer wall
        ([[1.0, 1.0, 0.0], [1.1, 1.0, 0.0]], "robots 0 and 1 overlap"),
        ([[1.0, 1.0, 0.0]], "2 finite rows"),
        ([[1.0, 1.0, float("nan")], [1.0, 2.0, 0.0]], "finite"),
    ):
        with pytest.raises(ConfigError, match=message):
            env.reset(seed=0, options={"poses": bad})


@pytest.mark.parametrize("angle", [0.0, 30.0, 60.0])
@pytest.mark.parametrize("jagged", [False, True])
def test_the_scene_is_the_floor_the_footprint_reaches(angle: float, jagged: bool) -> None:
    """One definition of the scene (``Scene.reachable_floor``): behind a doorway the footprint cannot
    pass (0.30 m for a 0.36 m robot), the far room is not part of the scene — not in Explo %'s
    denominator, no target, no start — and is reported as unreachable floor; through one it fits
    (0.9 m) the far room is part of it, all but a few cells per corner."""
    from areasearch.world import World
    from areasearch.config import WorldConfig

    for width, included in ((0.30, False), (0.90, True)):
        rooms = two_rooms(width, wall_angle_deg=angle, jagged=jagged)
        scene = scene_from_grid("rooms", rooms.free, rooms.cell_m)
        floor = scene.reachable_floor(0.18)
        # the room the team is not in (the rooms are alike: its region may be either)
        other = ~rooms.far if (scene.reachable(0.18) & rooms.far).sum() > (scene.reachable(0.18) & ~rooms.far).sum() else rooms.far
        far = other & scene.free
        assert floor[~scene.free].sum() == 0
        if included:
            assert floor[far].mean() > 0.97, (width, angle)
            assert scene.reachable_area_m2(0.18) > 0.97 * scene.free_area_m2
        else:
            # only the first radius + half a cell's diagonal beyond the team's region, in the doorway
            assert floor[far].sum() * scene.cell_m**2 < 0.05, (width, angle)
        world = World(WorldConfig(num_robots=3))
        world.reset(scene, np.random.default_rng(0))
        assert world.metrics.reachable_m2 == pytest.approx(floor.sum() * scene.cell_m**2)
        assert world.metrics.unreachable_m2 == pytest.approx((scene.free & ~floor).sum() * scene.cell_m**2)
        on_far = other[world.target_cells[:, 0], world.target_cells[:, 1]]
        starts = scene.world_to_cell(world.poses[:, :2])
        assert on_far.any() == included
        if not included:
            assert not other[starts[:, 0], starts[:, 1]].any()


def test_the_size_class_is_the_reachable_floors() -> None:
    """A map whose free floor is medium-sized but whose reachable part is small is small."""
    rooms = two_rooms(0.30, room_m=(4.5, 5.0))  # two 22.5 m² rooms, a doorway the robot cannot pass
    scene = scene_from_grid("rooms", rooms.free, rooms.cell_m)
    assert scene.free_area_m2 > 40.0
    assert scene.reachable_area_m2() < 25.0 and scene.size_class == "small"
    assert scene.size_class_for(0.10) == "medium"  # a robot of 0.2 m passes the 0.30 m doorway
