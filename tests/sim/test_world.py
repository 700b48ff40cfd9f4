"""World: motion and collisions, targets, metrics, reward, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from areasearch.config import RewardConfig, TargetConfig, WorldConfig, override
from areasearch.errors import ConfigError
from areasearch.sim.scene import load_scene, scene_from_grid
from areasearch.sim.world import Action, World

F, L, R, S = (int(a) for a in (Action.FORWARD, Action.TURN_LEFT, Action.TURN_RIGHT, Action.STAY))


def corridor(length_cells: int = 120, width_cells: int = 20):
    free = np.zeros((width_cells + 4, length_cells + 4), dtype=bool)
    free[2:-2, 2:-2] = True
    return scene_from_grid("corridor", free, 0.05)


def place(world: World, poses: list[tuple[float, float, float]]) -> None:
    """Put the robots at given poses (tests only) and re-sense."""
    world.poses[:] = np.array(poses)
    world.trajectory[world.metrics.steps] = world.poses
    world._sense()
    world._update_metrics()


def test_forward_and_turns_move_as_configured() -> None:
    world = World(WorldConfig(num_robots=1, targets=TargetConfig(count=5)))
    world.reset(corridor(), np.random.default_rng(0))
    place(world, [(1.0, 0.6, 0.0)])
    world.step(np.array([F]))
    np.testing.assert_allclose(world.poses[0], [1.25, 0.6, 0.0], atol=1e-12)
    world.step(np.array([L]))
    assert world.poses[0, 2] == pytest.approx(math.radians(10))
    world.step(np.array([R]))
    world.step(np.array([R]))
    assert world.poses[0, 2] == pytest.approx(-math.radians(10))
    world.step(np.array([S]))
    assert world.metrics.path_length_m[0] == pytest.approx(0.25)
    assert world.metrics.steps == 5


def test_wall_blocks_the_footprint_and_counts_a_collision() -> None:
    world = World(WorldConfig(num_robots=1, targets=TargetConfig(count=5)))
    scene = corridor()
    world.reset(scene, np.random.default_rng(0))
    place(world, [(1.0, 0.6, math.pi / 2)])  # facing the north wall at y = 1.1 m
    for _ in range(5):
        world.step(np.array([F]))
    # the footprint (0.18 m) never crosses the wall
    assert world.poses[0, 1] + 0.18 <= 1.1 + 1e-9
    assert world.metrics.collisions[0] >= 3


def test_a_thin_wall_cannot_be_jumped_over() -> None:
    free = np.zeros((24, 124), dtype=bool)
    free[2:-2, 2:-2] = True
    free[2:-2, 60] = False  # a one-cell (5 cm) wall across the corridor
    # the scene keeps the larger side only; the robot starts there and must never cross x = 3.0 m
    world = World(WorldConfig(num_robots=1, targets=TargetConfig(count=5)))
    scene = scene_from_grid("thin", free, 0.05)
    world.reset(scene, np.random.default_rng(0))
    side = world.poses[0, 0] < 3.0
    for _ in range(200):
        world.step(np.array([F if _ % 7 else L]))
        assert (world.poses[0, 0] < 3.0) == side


def test_robots_do_not_overlap() -> None:
    world = World(WorldConfig(num_robots=2, targets=TargetConfig(count=5)))
    world.reset(corridor(), np.random.default_rng(0))
    place(world, [(1.0, 0.6, 0.0), (1.7, 0.6, math.pi)])  # facing each other, 0.7 m apart
    result = world.step(np.array([F, F]))
    assert result.collided.tolist() == [False, True]  # robot 0 moves first, then robot 1 is blocked
    gap = np.hypot(*(world.poses[0, :2] - world.poses[1, :2]))
    assert gap >= 2 * 0.18


def test_a_robot_cannot_brush_through_a_team_mate_on_the_way(small_map: str) -> None:
    """The team-mate stands beside the move: 0.362 m from its start and its end, 0.34 m from its
    middle (less than the 0.36 m the two footprints need): the move is blocked."""
    world = World(WorldConfig(num_robots=2, targets=TargetConfig(count=5)))
    world.reset(load_scene(small_map), np.random.default_rng(0))
    x, y = world.poses[0, :2]
    for beside, blocked in ((0.34, True), (0.37, False)):
        place(world, [(x, y, 0.0), (x + 0.125, y + beside, 0.0)])
        assert world.step(np.array([F, S])).collided.tolist() == [blocked, False], beside


def test_the_footprint_may_not_overlap_a_wall_square_anywhere_on_a_move() -> None:
    """A wall cell's corner 0.17 m from the middle of a move, 0.2 m from both ends: blocked (a
    check at sample points of the move could miss it); 0.19 m: the move happens."""
    free = np.ones((40, 40), dtype=bool)
    free[[0, -1], :] = free[:, [0, -1]] = False
    for gap, blocked in ((0.17, True), (0.19, False)):
        grid = free.copy()
        grid[20, 20] = False  # its square's south-west corner at (1.0, 1.0)
        world = World(WorldConfig(num_robots=1, targets=TargetConfig(count=1)))
        world.reset(scene_from_grid("corner", grid, 0.05), np.random.default_rng(0))
        place(world, [(1.0 - 0.125, 1.0 - gap, 0.0)])
        assert world.step(np.array([F])).collided.tolist() == [blocked], gap


def test_bad_actions_raise(small_map: str) -> None:
    world = World(WorldConfig(num_robots=2))
    world.reset(load_scene(small_map), np.random.default_rng(0))
    with pytest.raises(ConfigError, match="actions"):
        world.step(np.array([0, 7]))
    with pytest.raises(ConfigError, match="actions"):
        world.step(np.array([0]))
    with pytest.raises(ConfigError, match="actions"):
        world.step(np.array([0.5, 1.0]))


def test_targets_are_discovered_then_covered() -> None:
    world = World(WorldConfig(num_robots=1, protocol="passby", targets=TargetConfig(count=60, cover_radius_m=0.3)))
    world.reset(corridor(length_cells=100), np.random.default_rng(1))
    assert not (world.covered & ~world.discovered).any()
    covered_at_start = world.covered.copy()  # seen and reached from the drawn start pose
    start = world.poses[0, :2].copy()
    for xy in world.targets_xy[covered_at_start]:
        assert np.hypot(*(xy - start)) <= 0.3
    # drive 2 m along the 5 m corridor, then turn round: everything gets discovered
    place(world, [(0.4, 0.6, 0.0)])
    for _ in range(8):
        world.step(np.array([F]))
    for _ in range(18):
        world.step(np.array([L]))
    assert world.discovered.all()
    path = world.trajectory[: world.metrics.steps + 1, 0, :2]
    for k in np.flatnonzero(~covered_at_start):
        near = np.hypot(*(path - world.targets_xy[k]).T) <= 0.3 + 1e-9  # (steps + 1,)
        after = np.arange(len(path)) >= world.discovered_at[k]
        if world.covered[k]:
            assert world.covered_at[k] >= world.discovered_at[k]
            assert near[world.covered_at[k]]
            assert not (near & after)[: world.covered_at[k]].any()  # covered at the first chance
        else:
            assert not (near & after).any()
    assert world.covered.any()
    # the map's target channel shows exactly the discovered, uncovered targets
    cells = world.target_cells[world.discovered & ~world.covered]
    assert world.mapper.targets.sum() == len(cells)
    assert world.mapper.targets[cells[:, 0], cells[:, 1]].all()


def test_targets_lie_on_free_cells_a_robot_can_cover() -> None:
    scene = load_scene("robotathome_sarmis")
    world = World(WorldConfig(num_robots=3))
    world.reset(scene, np.random.default_rng(2))
    cells = world.target_cells
    assert len(cells) == 100 and len(np.unique(cells, axis=0)) == 100
    assert scene.free[cells[:, 0], cells[:, 1]].all()
    reach = scene.cell_to_world(np.argwhere(scene.reachable(0.18)))
    for xy in world.targets_xy[:20]:
        assert np.hypot(*(reach - xy).T).min() <= 0.3


def test_metrics_and_reward_follow_the_paper() -> None:
    rewards = RewardConfig(explore_per_m2=0.2, cover_per_target=1.5, time_per_step=-0.01)
    world = World(WorldConfig(num_robots=3, reward=rewards))
    world.reset(load_scene("robotathome_sarmis"), np.random.default_rng(3))
    rng = np.random.default_rng(4)
    previous = world.metrics.explored_m2
    for _ in range(300):
        result = world.step(rng.integers(0, 3, size=3))
        m = world.metrics
        assert m.explored_m2 >= previous
        expected = 0.2 * (m.explored_m2 - previous) + 1.5 * result.new_covered - 0.01
        assert result.reward == pytest.approx(expected)
        previous = m.explored_m2
        assert 0.0 <= m.explored_fraction <= 1.0 and 0.0 <= m.covered_fraction <= 1.0
    floor = world.scene.reachable_floor(0.18)
    explored_floor = (world.mapper.explored & floor).sum()
    assert world.metrics.explored_fraction == pytest.approx(explored_floor / floor.sum())
    assert world.metrics.reachable_m2 == pytest.approx(floor.sum() * world.scene.cell_m**2)
    assert world.metrics.unreachable_m2 == pytest.approx((world.scene.free & ~floor).sum() * world.scene.cell_m**2)
    assert world.metrics.unreachable_m2 > 5.0  # robotathome_sarmis: rooms behind gaps narrower than the robot
    assert world.metrics.covered == world.covered.sum()


def test_time_e_is_the_first_step_reaching_the_fraction(small_map: str) -> None:
    config = WorldConfig(num_robots=2, success_fraction=0.3)
    world = World(config)
    world.reset(load_scene(small_map), np.random.default_rng(0))
    rng = np.random.default_rng(0)
    history = [world.metrics.explored_fraction]
    while not world.metrics.reached_e and world.metrics.steps < 2000:
        assert world.metrics.time_e == config.max_steps  # not reached (yet): the horizon
        world.step(rng.integers(0, 3, size=2))
        history.append(world.metrics.explored_fraction)
    assert world.metrics.reached_e
    first = next(i for i, f in enumerate(history) if f >= 0.3)
    assert world.metrics.time_e == first
    for _ in range(20):
        world.step(rng.integers(0, 3, size=2))
    assert world.metrics.time_e == first  # frozen once reached


def test_same_seed_same_episode_bit_for_bit() -> None:
    def run(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        world = World(WorldConfig(num_robots=4))
        rng = np.random.default_rng(seed)
        world.reset(load_scene("procedural:medium", rng), rng)
        for _ in range(150):
            world.step(rng.integers(0, 4, size=4))
        return world.trajectory[:151].copy(), world.mapper.channels(), world.depth.copy()

    a, b = run(7), run(7)
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x, y)
    c = run(8)
    assert not np.array_equal(a[0], c[0])


def test_start_poses_are_distinct_and_in_free_space(small_map: str) -> None:
    scene = load_scene(small_map)
    world = World(WorldConfig(num_robots=8))
    for seed in range(5):
        world.reset(scene, np.random.default_rng(seed))
        cells = scene.world_to_cell(world.poses[:, :2])
        assert scene.reachable(0.18)[cells[:, 0], cells[:, 1]].all()
        d = np.hypot(*(world.poses[:, None, :2] - world.poses[None, :, :2]).transpose(2, 0, 1))
        assert (d[~np.eye(8, dtype=bool)] >= 0.36).all()


def test_too_many_robots_for_the_map_is_a_config_error(small_map: str) -> None:
    world = World(override(WorldConfig(num_robots=8), **{"robot.radius_m": 1.0}))
    with pytest.raises(ConfigError, match="cannot place 8 robots"):
        world.reset(load_scene(small_map), np.random.default_rng(0))


@pytest.mark.parametrize(
    "changes, field",
    [
        ({"num_robots": 0}, "num_robots"),
        ({"num_robots": 9}, "num_robots"),
        ({"robot.radius_m": -0.1}, "robot.radius_m"),
        ({"robot.forward_m": 0}, "robot.forward_m"),
        ({"camera.width_px": 1}, "camera.width_px"),
        ({"camera.hfov_deg": 190}, "camera.hfov_deg"),
        ({"targets.count": -1}, "targets.count"),
        ({"targets.cover_radius_m": float("nan")}, "targets.cover_radius_m"),
        ({"max_steps": 0}, "max_steps"),
    ],
)
def test_bad_config_names_the_field(changes: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        World(override(WorldConfig(), **changes))


def test_a_bounce_walk_explores_but_leaves_targets_uncovered() -> None:
    """The cover radius makes covering deliberate: seeing a target is not reaching it."""
    from areasearch.sim.actions import bounce_walk

    world = World(WorldConfig(num_robots=3, max_steps=800))
    rng = np.random.default_rng(0)
    world.reset(load_scene("robotathome_sarmis"), rng)
    collided = np.zeros(3, dtype=bool)
    turning = np.zeros(3, dtype=np.int64)
    for _ in range(800):
        collided = world.step(bounce_walk(collided, turning, rng)).collided
    m = world.metrics
    assert m.explored_fraction > 0.5
    assert m.covered < 0.6 * m.discovered


@pytest.mark.parametrize("map_spec", ["robotathome_sarmis", "procedural:medium"])
def test_sensing_equals_rendering_then_mapping(map_spec: str) -> None:
    """The world renders and maps in one pass (reusing the renderer's ray walk for the mapper's
    carve): it must give exactly what render_depth followed by Mapper.integrate gives."""
    from areasearch.sim.actions import bounce_walk
    from areasearch.sim.depth import render_depth
    from areasearch.sim.mapper import Mapper

    world = World(WorldConfig(num_robots=4, max_steps=400))
    rng = np.random.default_rng(3)
    scene = load_scene(map_spec, rng)
    world.reset(scene, rng)
    cfg = world.config
    mapper = Mapper(scene.shape, scene.cell_m, scene.origin_xy, obstacle_top_m=cfg.robot.height_m)
    depth = render_depth(scene.height_m, scene.cell_m, scene.origin_xy, world.poses, cfg.camera)
    mapper.integrate(depth, cfg.camera, world.poses)
    collided = np.zeros(4, dtype=bool)
    turning = np.zeros(4, dtype=np.int64)
    for step in range(400):
        before = world.mapper.explored.sum()
        collided = world.step(bounce_walk(collided, turning, rng)).collided
        depth = render_depth(scene.height_m, scene.cell_m, scene.origin_xy, world.poses, cfg.camera)
        new = mapper.integrate(depth, cfg.camera, world.poses)
        assert np.array_equal(world.depth, depth), step
        assert np.array_equal(world.mapper.explored, mapper.explored), step
        assert np.array_equal(world.mapper.occupied, mapper.occupied), step
        assert np.array_equal(world.mapper.occupied_at, mapper.occupied_at), step
        assert world.mapper.explored.sum() - before == len(new)


def test_skipping_robots_that_did_not_move_changes_nothing() -> None:
    # A robot whose pose is unchanged since it last sensed is not rendered again; the map, the depth
    # images, the targets and the metrics must be those of re-sensing every robot every step.
    scene = load_scene("robotathome_sarmis")
    rng = np.random.default_rng(3)
    script = rng.choice([F, F, L, R, S, S, S], size=(120, 3))
    worlds = []
    for resense_all in (False, True):
        world = World(WorldConfig(num_robots=3))
        world.reset(scene, np.random.default_rng(0))
        for actions in script:
            if resense_all:
                world._sensed[:] = np.nan  # forget the last poses: every robot renders and fuses
            world.step(actions)
        worlds.append(world)
    skip, full = worlds
    assert np.isnan(full._sensed).sum() == 0
    np.testing.assert_array_equal(skip.mapper.explored, full.mapper.explored)
    np.testing.assert_array_equal(skip.mapper.occupied, full.mapper.occupied)
    np.testing.assert_array_equal(skip.mapper.occupied_at, full.mapper.occupied_at)
    np.testing.assert_array_equal(skip.depth, full.depth)
    np.testing.assert_array_equal(skip.covered_at, full.covered_at)
    np.testing.assert_array_equal(skip.discovered_at, full.discovered_at)
    assert skip.metrics.explored_m2 == full.metrics.explored_m2
    assert (script == S).any(axis=1).sum() > 50  # the script has robots standing still
