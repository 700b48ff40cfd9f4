"""Depth camera and reconstruction mapper against ground truth on hand-built maps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from areasearch.config import CameraConfig
from areasearch.sim.depth import camera_tables, render_depth
from areasearch.sim.mapper import Mapper
from areasearch.sim.scene import Scene, scene_from_grid

CELL = 0.05


def room_with_furniture() -> Scene:
    """A 4 m x 3 m room, a 0.5 m high table, a full-height pillar and a thin inner wall with a door."""
    free = np.zeros((70, 90), dtype=bool)
    free[5:65, 5:85] = True
    heights = np.zeros(free.shape, dtype=np.float32)
    heights[20:30, 20:36] = 0.5  # table, 0.5 m x 0.8 m
    free[20:30, 20:36] = False
    free[40:46, 60:66] = False  # pillar (wall height)
    free[5:65, 70] = False  # thin wall...
    free[30:50, 70] = True  # ...with a 1 m door
    return scene_from_grid("room", free, CELL, height_m=heights, wall_height_m=2.5)


def reference_depth(scene: Scene, pose: np.ndarray, camera: CameraConfig, step_m: float = 0.002) -> np.ndarray:
    """Brute force: march every pixel's 3D ray in small steps until it enters the floor or an obstacle."""
    tables = camera_tables(camera)
    xu, slope = np.meshgrid(tables.xu, tables.slope)  # (H, W)
    x, y, yaw = pose
    fwd = np.array([math.cos(yaw), math.sin(yaw)])
    right = np.array([math.sin(yaw), -math.cos(yaw)])
    out = np.zeros(xu.shape)
    open_ = np.ones(xu.shape, dtype=bool)
    stretch = np.sqrt(1 + xu**2 + slope**2)
    for z in np.arange(step_m, camera.max_range_m + step_m, step_m):
        px = x + z * (fwd[0] + xu * right[0])
        py = y + z * (fwd[1] + xu * right[1])
        pz = camera.mount_height_m + slope * z
        ix = np.floor((px - scene.origin_xy[0]) / scene.cell_m).astype(int)
        iy = np.floor((py - scene.origin_xy[1]) / scene.cell_m).astype(int)
        h = scene.height_m[np.clip(iy, 0, scene.shape[0] - 1), np.clip(ix, 0, scene.shape[1] - 1)]
        hit = open_ & ((pz <= 0) | (pz <= h))
        in_range = z * stretch <= camera.max_range_m
        out[hit & in_range] = z
        open_ &= ~hit
        if not open_.any():
            break
    return out


POSES = [
    np.array([0.6, 0.6, 0.3]),
    np.array([2.5, 2.0, -1.2]),
    np.array([3.3, 1.2, math.pi * 0.75]),
    np.array([0.6, 2.8, -0.4]),
]


@pytest.mark.parametrize("pose", POSES, ids=range(len(POSES)))
def test_depth_matches_brute_force_ray_marching(pose: np.ndarray) -> None:
    scene = room_with_furniture()
    camera = CameraConfig(width_px=24, height_px=18)
    depth = render_depth(scene.height_m, scene.cell_m, scene.origin_xy, pose[None], camera)[0]
    ref = reference_depth(scene, pose, camera)
    both = (depth > 0) & (ref > 0)
    # the marcher overshoots by at most one step; pixels near the range limit may flip to no-return
    assert both.sum() >= 0.97 * max((depth > 0).sum(), (ref > 0).sum())
    np.testing.assert_allclose(depth[both], ref[both], atol=0.005)


def test_depth_facing_a_wall_is_the_wall_distance() -> None:
    free = np.zeros((40, 80), dtype=bool)
    free[2:38, 2:60] = True  # east wall starts at x = 3.0 m
    scene = scene_from_grid("box", free, CELL)
    camera = CameraConfig()
    pose = np.array([[1.0, 1.0, 0.0]])  # looking east, 2.0 m from the wall
    depth = render_depth(scene.height_m, scene.cell_m, scene.origin_xy, pose, camera)[0]
    tables = camera_tables(camera)
    centre_col = camera.width_px // 2
    wall_rows = tables.slope > -camera.mount_height_m / 2.0  # rows meeting the wall above the floor
    np.testing.assert_allclose(depth[wall_rows, centre_col], 2.0, atol=1e-4)
    floor_rows = ~wall_rows & (tables.floor_depth[centre_col] > 0)
    np.testing.assert_allclose(
        depth[floor_rows, centre_col], camera.mount_height_m / -tables.slope[floor_rows], rtol=1e-5
    )


def test_depth_beyond_range_is_zero() -> None:
    free = np.zeros((40, 300), dtype=bool)
    free[2:38, 2:298] = True
    scene = scene_from_grid("hall", free, CELL)
    camera = CameraConfig(max_range_m=2.0)
    depth = render_depth(scene.height_m, scene.cell_m, scene.origin_xy, np.array([[0.5, 1.0, 0.0]]), camera)[0]
    stretch = np.sqrt(1 + camera_tables(camera).xu[None, :] ** 2 + camera_tables(camera).slope[:, None] ** 2)
    assert np.all(depth * stretch <= 2.0 + 1e-6)
    assert (depth == 0).any()  # looking along a 15 m hall: the horizon is out of range


def visible_cells(scene: Scene, pose: np.ndarray, camera: CameraConfig, reach_m: float) -> np.ndarray:
    """Free cells within the horizontal FOV, ``reach_m`` of the camera and in 2D line of sight."""
    ys, xs = np.nonzero(scene.free)
    centres = scene.cell_to_world(np.stack([ys, xs], 1))
    rel = centres - pose[:2]
    dist = np.hypot(rel[:, 0], rel[:, 1])
    bearing = np.arctan2(rel[:, 1], rel[:, 0]) - pose[2]
    bearing = (bearing + np.pi) % (2 * np.pi) - np.pi
    keep = (dist <= reach_m) & (np.abs(bearing) <= math.radians(camera.hfov_deg) / 2 - 0.03) & (dist > 0.3)
    out = np.zeros(scene.shape, dtype=bool)
    for (iy, ix), d, rx, ry in zip(np.stack([ys, xs], 1)[keep], dist[keep], rel[keep, 0], rel[keep, 1], strict=True):
        t = np.linspace(0, 1, max(2, int(d / 0.01)))
        cells = scene.world_to_cell(pose[:2] + np.stack([t * rx, t * ry], 1))
        if np.all(scene.free[cells[:, 0], cells[:, 1]]):
            out[iy, ix] = True
    return out


def test_mapper_agrees_with_ground_truth_inside_the_sensor_footprint() -> None:
    scene = room_with_furniture()
    camera = CameraConfig(width_px=128, height_px=64)
    mapper = Mapper(scene.shape, scene.cell_m, scene.origin_xy, obstacle_top_m=0.6)
    for pose in POSES:
        depth = render_depth(scene.height_m, scene.cell_m, scene.origin_xy, pose[None], camera)
        mapper.integrate(depth, camera, pose[None])
        # soundness: every mapped obstacle is a real obstacle, every known-free cell is real floor
        assert not (mapper.occupied & scene.free).any()
        assert not (mapper.known_free & ~scene.free).any()
        # completeness: what the camera can see (floor rows reach ~3 m) is explored
        seen = visible_cells(scene, pose, camera, reach_m=2.5)
        assert seen.sum() > 200
        assert (mapper.explored & seen).sum() >= 0.97 * seen.sum()
    # the table, the pillar and the thin wall were all seen and mapped
    assert mapper.occupied[20:30, 20:36].any()
    assert mapper.occupied[40:46, 60:66].any()
    assert mapper.occupied[:, 70].sum() >= 10


def test_mapper_accepts_depth_from_any_source_and_reports_new_cells() -> None:
    """A synthetic depth image (a flat wall 1 m ahead, every pixel) maps one wall segment."""
    camera = CameraConfig(width_px=32, height_px=24)
    mapper = Mapper((60, 60), 0.05, (0.0, 0.0), obstacle_top_m=0.6)
    depth = np.full((1, 24, 32), 1.0, dtype=np.float32)
    pose = np.array([[0.5, 1.5, 0.0]])
    new = mapper.integrate(depth, camera, pose)
    assert len(new) == mapper.explored.sum() > 0
    occupied_x = np.nonzero(mapper.occupied)[1]
    assert set(occupied_x.tolist()) == {30}  # x = 1.5 m -> column 30
    assert len(mapper.integrate(depth, camera, pose)) == 0  # nothing new the second time
    channels = mapper.channels()
    assert channels.shape == (3, 60, 60) and channels.dtype == np.uint8


def test_mapper_takes_non_finite_depth_as_no_return() -> None:
    """NaN and infinite pixels of a sensor's image map as 0 (no return) does, and the image is left alone."""
    camera = CameraConfig(width_px=32, height_px=24)
    depth = np.full((1, 24, 32), 1.0, dtype=np.float32)
    depth[0, :, 3] = np.inf
    depth[0, 5:, 20] = np.nan
    depth[0, :4, 9] = -np.inf
    pose = np.array([[0.5, 1.5, 0.3]])
    given = depth.copy()
    bad, zero = Mapper((60, 60), 0.05), Mapper((60, 60), 0.05)
    new = bad.integrate(depth, camera, pose)
    np.testing.assert_array_equal(new, zero.integrate(np.where(np.isfinite(depth), depth, 0), camera, pose))
    np.testing.assert_array_equal(bad.explored, zero.explored)
    np.testing.assert_array_equal(bad.occupied, zero.occupied)
    np.testing.assert_array_equal(depth, given)


def test_mapper_rejects_mismatched_shapes() -> None:
    camera = CameraConfig(width_px=32, height_px=24)
    mapper = Mapper((20, 20), 0.05)
    with pytest.raises(ValueError, match="does not match"):
        mapper.integrate(np.zeros((2, 24, 32), np.float32), camera, np.zeros((1, 3)))


@pytest.mark.parametrize("map_spec", ["robotathome_sarmis", "giraff_home_delcegno", "procedural:medium"])
def test_mapper_stays_sound_over_long_episodes_on_real_maps(map_spec: str) -> None:
    """Millions of depth points, grazing hits at cell corners included: no mapped obstacle on real
    floor, no known-free cell on a real obstacle."""
    from areasearch.config import WorldConfig
    from areasearch.sim.actions import bounce_walk
    from areasearch.sim.scene import load_scene
    from areasearch.sim.world import World

    rng = np.random.default_rng(0)
    scene = load_scene(map_spec, rng)
    world = World(WorldConfig(num_robots=4))
    world.reset(scene, rng)
    collided = np.zeros(4, dtype=bool)
    turning = np.zeros(4, dtype=np.int64)
    for _ in range(1200):
        collided = world.step(bounce_walk(collided, turning, rng)).collided
    assert world.metrics.explored_fraction > 0.4
    assert not (world.mapper.occupied & scene.free).any()
    assert not (world.mapper.known_free & ~scene.free).any()
