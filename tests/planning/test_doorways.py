"""The doorway test geometry (``layouts.two_rooms``): widths, angles, thickness, jagged edges."""

from __future__ import annotations

import numpy as np
import pytest

from areasearch.envs.goal import AreaSearchEnv, nearest_candidate
from areasearch.sim.layouts import two_rooms
from areasearch.sim.scene import scene_from_grid

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
    from areasearch.config import WorldConfig
    from areasearch.sim.world import World

    for width, included in ((0.30, False), (0.90, True)):
        rooms = two_rooms(width, wall_angle_deg=angle, jagged=jagged)
        scene = scene_from_grid("rooms", rooms.free, rooms.cell_m)
        floor = scene.reachable_floor(0.18)
        # the room the team is not in (the rooms are alike: its region may be either)
        other = (
            ~rooms.far
            if (scene.reachable(0.18) & rooms.far).sum() > (scene.reachable(0.18) & ~rooms.far).sum()
            else rooms.far
        )
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


# ---------------------------------------------------------------------------------- the doorway suite

SUITE_WIDTHS = (0.40, 0.45, 0.50, 0.60, 0.90)
"""Clear widths, metres: from just above the footprint's diameter (0.36 m) to 0.9 m."""
SUITE_ANGLES = (0.0, 30.0, 60.0)
SUITE_WALLS = (0.05, 0.20)
"""Wall thickness: one cell, and 0.2 m."""
CLASSICAL = ("greedy", "utility", "voronoi", "coscan", "hungarian", "random")
SUITE_TEAMS = (1, 3, 5)
SUITE_STEPS = 2000
"""The step bound: every team must be in the far room and have covered its targets by then."""
SUITE = [(w, a, t, j) for w in SUITE_WIDTHS for a in SUITE_ANGLES for t in SUITE_WALLS for j in (False, True)]


def _suite_id(case: tuple[float, float, float, bool]) -> str:
    w, a, t, j = case
    return f"{w:.2f}m-{a:g}deg-{t:.2f}wall-{'jagged' if j else 'clean'}"


@pytest.mark.parametrize("case", SUITE, ids=_suite_id)
def test_the_doorway_suite_far_room_is_in_the_scene_exactly_when_the_footprint_fits(
    case: tuple[float, float, float, bool],
) -> None:
    """Both rooms are in the scene when the world's rule lets the footprint through the doorway (the
    team's region spans both rooms), only the team's room otherwise; no target is ever placed where
    the footprint does not reach."""
    from areasearch.config import WorldConfig
    from areasearch.sim.world import World

    width, angle, wall, jagged = case
    rooms = two_rooms(width, wall_angle_deg=angle, wall_m=wall, jagged=jagged)
    scene = scene_from_grid("rooms", rooms.free, rooms.cell_m)
    region = scene.reachable(0.18)
    fits = bool((region & rooms.far).any() and (region & ~rooms.far).any())
    floor = scene.reachable_floor(0.18)
    other = ~rooms.far if (region & rooms.far).sum() > (region & ~rooms.far).sum() else rooms.far
    if fits:
        assert floor[rooms.far & scene.free].mean() > 0.95 and floor[~rooms.far & scene.free].mean() > 0.95
    else:
        assert floor[other].sum() * scene.cell_m**2 < 0.05  # the doorway's first cells at most
        world = World(WorldConfig(num_robots=1))
        world.reset(scene, np.random.default_rng(0))
        assert not other[world.target_cells[:, 0], world.target_cells[:, 1]].any()
    assert fits == (_suite_id(case) not in TOO_NARROW)


def _through(scene, rooms, method: str, robots: int, seed: int = 0) -> tuple[int, dict]:
    """Play ``method`` with ``robots`` started in the west room, ten targets; the first step a robot
    centre was in the far room (-1: never) and the last info."""
    from areasearch.planners import make_planner
    from areasearch.sim.world import sample_start_poses

    region = scene.reachable(0.18) & ~rooms.far
    poses = sample_start_poses(scene, region, robots, 0.18, np.random.default_rng(seed))
    env = AreaSearchEnv(map=scene, num_robots=robots, seed=seed, max_steps=SUITE_STEPS, **{"targets.count": 10})
    obs, info = env.reset(seed=seed, options={"poses": poses})
    planner = make_planner(method)
    planner.reset(np.random.default_rng(seed))
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(planner.assign(obs))
        done = terminated or truncated
    cells = scene.world_to_cell(env.world.trajectory[: info["steps"] + 1, :, :2])
    inside = rooms.far[cells[..., 0], cells[..., 1]].any(axis=1)
    return (int(np.argmax(inside)) if inside.any() else -1), info


TOO_NARROW = {
    *(f"0.40m-{a}deg-{t}wall-{e}" for a in (0, 30) for t in ("0.05", "0.20") for e in ("clean", "jagged")),
    "0.40m-60deg-0.20wall-clean",
    "0.40m-60deg-0.20wall-jagged",
    "0.45m-0deg-0.05wall-jagged",
    "0.45m-0deg-0.20wall-jagged",
    "0.45m-30deg-0.20wall-jagged",
    "0.45m-60deg-0.20wall-jagged",
}
"""The geometries of the suite that the footprint cannot pass by the world's rule (no cell centre
of the doorway is 0.18 m from every wall square; a jagged edge's notches narrow its doorway): the
0.40 m doorways but in a one-cell wall slanted 60° (its rasterised gap is wider), the jagged 0.45 m
ones but in a one-cell wall slanted 30° or 60°. Every doorway of 0.5 m or more fits."""

PASSED = [case for case in SUITE if _suite_id(case) not in TOO_NARROW]
"""The geometries every team must get through in the test below: all those the footprint fits."""


KNOWN_FAILURES: dict[str, set[tuple[str, int]]] = {}
"""Runs of the suite below that fail today, pinned so that a fix (or a new failure) shows: none."""


@pytest.mark.slow
@pytest.mark.parametrize("case", PASSED, ids=_suite_id)
def test_the_doorway_suite_teams_of_1_3_and_5_get_through_and_finish(case: tuple[float, float, float, bool]) -> None:
    """A single robot, a team of 3 and a team of 5 started in the west room get a robot into the far
    room and finish — everything explored and the ten targets (some in the far room) covered —
    within ``SUITE_STEPS`` steps. One classical planner per geometry, in turn over the suite (all
    six planners on every geometry: ``benchmarks/bench_doorways.py``)."""
    width, angle, wall, jagged = case
    rooms = two_rooms(width, wall_angle_deg=angle, wall_m=wall, jagged=jagged)
    scene = scene_from_grid("rooms", rooms.free, rooms.cell_m)
    method = CLASSICAL[PASSED.index(case) % len(CLASSICAL)]
    failed, why = set(), []
    for robots in SUITE_TEAMS:
        step, info = _through(scene, rooms, method, robots)
        if step < 0 or info["covered_pct"] < 100.0 or info["explored_pct"] < 100.0:
            failed.add((method, robots))
            why.append(
                f"{method} x{robots}: far room at {step}, {info['explored_pct']:.1f} % explored, "
                f"{info['covered_pct']:.0f} % covered at step {info['steps']}"
            )
    assert failed == KNOWN_FAILURES.get(_suite_id(case), set()), "; ".join(why) or "a known failure now passes"


@pytest.mark.slow
def test_a_one_cell_staircase_doorway_is_passed() -> None:
    """A 0.45 m doorway in a 0.2 m wall slanted 30°: the cells of its way through touch only at
    corners in places (a staircase), which no sequence of moves could follow while the world judged a
    robot by the cell of its centre; judged by its footprint against the wall's squares (the world's
    rule), the way through is straight and 0.09 m wide, and a single robot passes."""
    rooms = two_rooms(0.45, wall_angle_deg=30.0, wall_m=0.2)
    scene = scene_from_grid("rooms", rooms.free, rooms.cell_m)
    region = scene.reachable(0.18)
    assert (region & rooms.far).any() and (region & ~rooms.far).any()
    step, info = _through(scene, rooms, "greedy", 1)
    assert step >= 0 and info["explored_pct"] == 100.0 and info["covered_pct"] == 100.0


@pytest.mark.slow
def test_greedy_x3_through_a_jagged_60cm_doorway_in_a_slanted_thick_wall() -> None:
    """A doorway case that once failed: a robot backing off for a team-mate in the doorway
    aimed at the next cell of its path, 3.5 cm west of its centre and so straight at the team-mate;
    its FORWARD was held at every step while the team-mate, facing it, was held too. The short-term
    goal now lies at least ``paths.min_aim_m`` away (the path's direction, not the cell's corner)."""
    rooms = two_rooms(0.6, wall_angle_deg=30.0, wall_m=0.2, jagged=True)
    scene = scene_from_grid("rooms", rooms.free, rooms.cell_m)
    step, info = _through(scene, rooms, "greedy", 3)
    assert step >= 0 and info["explored_pct"] == 100.0 and info["covered_pct"] == 100.0
