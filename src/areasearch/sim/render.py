"""Drawing: top-down RGB pictures of a search episode (the only module that draws).

North is up. Colours: unexplored ground truth in greys (free light, obstacles darker), explored
free floor white, mapped obstacles black, discovered targets red, covered targets green, frontier
nodes blue diamonds, each robot a triangle pointing along its heading in its own colour, with its
trajectory and its long-term goal as a square.

:func:`draw_world` draws the team map with the robots where they truly are (or, with ``truth=True``,
the map a perfect mapper at the true poses would have made: :func:`areasearch.sim.mapquality.true_map`);
:func:`draw_belief` draws what the team (or one robot) believes: its map, the robots at their believed
poses and the targets where the map marks them, over the same ground-truth greys, so that a map blurred
or shifted by noise shows against the true walls.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from ..folderlock import write_atomic
from .mapper import Mapper
from .mapquality import true_map
from .world import World

ROBOT_COLOURS = np.array(
    [
        (31, 119, 180),
        (255, 127, 14),
        (148, 103, 189),
        (23, 190, 207),
        (188, 189, 34),
        (227, 119, 194),
        (140, 86, 75),
        (44, 160, 44),
    ],
    dtype=np.uint8,
)
UNKNOWN_FREE = (205, 205, 205)
UNKNOWN_OBSTACLE = (120, 120, 120)
EXPLORED_FREE = (255, 255, 255)
MAPPED_OBSTACLE = (20, 20, 20)
TARGET_FOUND = (220, 30, 30)
TARGET_COVERED = (30, 150, 60)
FRONTIER_NODE = (0, 90, 255)


def default_scale(shape: tuple[int, int], target_px: int = 640) -> int:
    """Integer upscaling so that the longer side of the picture is about ``target_px``."""
    return max(1, int(round(target_px / max(shape))))


def draw_world(
    world: World,
    scale: int | None = None,
    *,
    goals: np.ndarray | None = None,
    candidates: Any = None,
    truth: bool = False,
) -> np.ndarray:
    """(H*scale, W*scale, 3) uint8 picture of the world's current state.

    ``goals`` (R, 2) cells (rows of -1 for none) are drawn as squares in each robot's colour;
    ``candidates`` (anything with ``cells`` and ``kind``) as small hollow diamonds (frontier nodes).
    ``truth``: draw the map a perfect mapper at the true poses would have made instead of the team map
    (they are the same with every imperfection off).
    """
    scene, mapper = world.scene, world.mapper
    if scene is None or mapper is None:
        raise RuntimeError("draw_world needs a World that was reset")
    scale = scale or default_scale(scene.shape)
    explored, occupied = true_map(world) if truth else (mapper.explored, mapper.occupied)
    picture = _map_picture(world, explored, occupied, scale)
    draw = ImageDraw.Draw(picture)
    to_px = _to_px(world, scale)
    dot = max(2.0, 0.08 / scene.cell_m * scale)
    for state, colour in ((world.discovered & ~world.covered, TARGET_FOUND), (world.covered, TARGET_COVERED)):
        for x, y in to_px(world.targets_xy[state]):
            draw.ellipse((x - dot, y - dot, x + dot, y + dot), fill=colour)
    if candidates is not None and len(candidates.cells):
        frontier = np.asarray(candidates.kind) == 0
        for x, y in to_px(scene.cell_to_world(np.asarray(candidates.cells)[frontier])):
            d = dot * 1.6
            draw.polygon([(x, y - d), (x + d, y), (x, y + d), (x - d, y)], outline=FRONTIER_NODE)
    _draw_robots(draw, world, to_px, scale, world.poses, world.trajectory, goals)
    return np.asarray(picture)


def draw_belief(world: World, robot: int | None = None, scale: int | None = None) -> np.ndarray:
    """(H*scale, W*scale, 3) uint8 picture of what the team believes (``robot`` None) or what ``robot``
    believes: its map (:attr:`World.robot_maps <areasearch.sim.world.World.robot_maps>`; the team map with
    full communication) over the ground-truth greys, the team at the believed poses (where ``robot`` places
    it, :meth:`~areasearch.sim.world.World.team_poses`) with the believed trajectories, and the target marks
    of the map as red dots. With every imperfection off it shows the team map at the true poses."""
    scene = world.scene
    if scene is None or world.mapper is None:
        raise RuntimeError("draw_belief needs a World that was reset")
    scale = scale or default_scale(scene.shape)
    mapper: Mapper = world.mapper if robot is None else world.robot_maps[robot]
    picture = _map_picture(world, mapper.explored, mapper.occupied, scale)
    draw = ImageDraw.Draw(picture)
    to_px = _to_px(world, scale)
    dot = max(2.0, 0.08 / scene.cell_m * scale)
    for x, y in to_px(scene.cell_to_world(np.argwhere(mapper.targets))):
        draw.ellipse((x - dot, y - dot, x + dot, y + dot), fill=TARGET_FOUND)
    poses = world.believed_poses if robot is None else world.team_poses(robot)
    _draw_robots(draw, world, to_px, scale, poses, world.believed_trajectory, None)
    return np.asarray(picture)


def _map_picture(world: World, explored: np.ndarray, occupied: np.ndarray, scale: int) -> Image.Image:
    """The map layer: ground truth in greys, ``explored`` free floor white, ``occupied`` black, upscaled."""
    scene = world.scene
    assert scene is not None
    img = np.empty((*scene.shape, 3), dtype=np.uint8)
    img[:] = UNKNOWN_OBSTACLE
    img[scene.free] = UNKNOWN_FREE
    img[explored & ~occupied] = EXPLORED_FREE
    img[occupied] = MAPPED_OBSTACLE
    img = np.flipud(img)
    if scale > 1:
        img = img.repeat(scale, axis=0).repeat(scale, axis=1)
    return Image.fromarray(np.ascontiguousarray(img))


def _to_px(world: World, scale: int) -> Any:
    """A function: map-frame metres (..., 2) -> picture pixels (..., 2)."""
    scene = world.scene
    assert scene is not None
    height_px = scene.shape[0] * scale

    def to_px(xy: np.ndarray) -> np.ndarray:
        col = (xy[..., 0] - scene.origin_xy[0]) / scene.cell_m * scale
        row = height_px - (xy[..., 1] - scene.origin_xy[1]) / scene.cell_m * scale
        return np.stack([col, row], axis=-1)

    return to_px


def _draw_robots(
    draw: ImageDraw.ImageDraw,
    world: World,
    to_px: Any,
    scale: int,
    poses: np.ndarray,
    trajectory: np.ndarray,
    goals: np.ndarray | None,
) -> None:
    """Each robot as a triangle at ``poses`` (R, 3) along its heading, with its ``trajectory`` so far and its
    goal (``goals`` (R, 2) cells, rows of -1 for none) as a square, in its own colour."""
    scene = world.scene
    assert scene is not None
    steps = min(world.metrics.steps, len(trajectory) - 1)
    radius_px = max(4.0, world.config.robot.radius_m / scene.cell_m * scale * 1.3)
    for r in range(world.config.num_robots):
        red, green, blue = (int(c) for c in ROBOT_COLOURS[r % len(ROBOT_COLOURS)])
        colour = (red, green, blue)
        path = to_px(trajectory[: steps + 1, r, :2])
        if len(path) > 1:
            draw.line([tuple(p) for p in path], fill=colour, width=max(1, scale // 2))
        x, y = to_px(poses[r, :2])
        yaw = poses[r, 2]
        # picture rows grow southwards, so the heading's y component flips
        tip = (x + radius_px * math.cos(yaw), y - radius_px * math.sin(yaw))
        left = (x + radius_px * 0.7 * math.cos(yaw + 2.5), y - radius_px * 0.7 * math.sin(yaw + 2.5))
        right = (x + radius_px * 0.7 * math.cos(yaw - 2.5), y - radius_px * 0.7 * math.sin(yaw - 2.5))
        draw.polygon([tip, left, right], fill=colour, outline=(0, 0, 0))
        if goals is not None and goals[r, 0] >= 0:
            gx, gy = to_px(scene.cell_to_world(goals[r]))
            half = radius_px * 0.6
            draw.rectangle((gx - half, gy - half, gx + half, gy + half), outline=colour, width=max(2, scale))


def save_png(frame: np.ndarray, path: str | Path) -> Path:
    """Write an RGB frame as PNG atomically (:func:`areasearch.folderlock.write_atomic`: a failed write
    leaves the file as it was and no temporary file, and raises one AreaSearchError)."""
    buffer = io.BytesIO()
    Image.fromarray(frame).save(buffer, format="PNG")
    return write_atomic(path, buffer.getvalue(), "picture")
