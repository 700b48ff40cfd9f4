"""Where an episode's robots start and its targets lie: start poses drawn or checked by the world's collision
rule (:func:`sample_start_poses`, :func:`check_start_poses`) and targets drawn by the coverage protocol's
placement (:func:`draw_targets`). Apart from :mod:`areasearch.sim.world` so that the harness can draw an
episode's layout without a world, and the world module holds the episode's dynamics alone.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from ..config import WorldConfig
from ..errors import ConfigError
from .footprint import segment_hits
from .scene import Scene


def check_start_poses(scene: Scene, reachable: np.ndarray, poses: object, n: int, radius_m: float) -> np.ndarray:
    """``poses`` as a float (n, 3) array of start poses, checked: finite, each robot centre on a cell
    of ``reachable`` (the team's region) with its footprint clear of every obstacle cell (the
    world's rule), no two footprints overlapping; else a ConfigError naming the robot."""
    try:
        array = np.array(poses, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError("start poses must be numbers (x, y, yaw) per robot") from None
    if array.shape != (n, 3) or not np.isfinite(array).all():
        raise ConfigError(f"start poses must be {n} finite rows of (x, y, yaw), got shape {array.shape}")
    cells = scene.world_to_cell(array[:, :2])
    h, w = reachable.shape
    walls = ~scene.free
    ox, oy = scene.origin_xy
    for r, (iy, ix) in enumerate(cells):
        x, y = array[r, :2]
        if not (0 <= iy < h and 0 <= ix < w and reachable[iy, ix]) or segment_hits(
            walls, 0, 0, ox, oy, scene.cell_m, x, y, x, y, radius_m
        ):
            raise ConfigError(f"start pose of robot {r} at ({x:g}, {y:g}) is not where a robot can stand")
    for r in range(n):
        near = np.hypot(*(array[r + 1 :, :2] - array[r, :2]).T) < 2 * radius_m
        if near.any():
            raise ConfigError(f"start poses of robots {r} and {r + 1 + int(np.argmax(near))} overlap")
    array[:, 2] = (array[:, 2] + math.pi) % (2 * math.pi) - math.pi
    return array


def sample_start_poses(
    scene: Scene, reachable: np.ndarray, n: int, radius_m: float, rng: np.random.Generator
) -> np.ndarray:
    """Draw ``n`` distinct start poses (x, y, yaw) on ``reachable`` cells, footprints not overlapping."""
    cells = np.argwhere(reachable)
    if len(cells) == 0:
        raise ConfigError(
            f"{scene.name}: no room for a robot of radius {radius_m} m (no free cell is that far from every wall)"
        )
    poses = np.zeros((n, 3))
    placed = 0
    tries = 0
    min_sep2 = (2.0 * radius_m) ** 2 * 1.0001
    while placed < n:
        tries += 1
        if tries > 2000 + 200 * n:
            raise ConfigError(
                f"{scene.name}: cannot place {n} robots of radius {radius_m} m without overlap "
                f"(reachable area {reachable.sum() * scene.cell_m**2:.2f} m²); use fewer robots"
            )
        cell = cells[int(rng.integers(len(cells)))]
        xy = scene.cell_to_world(cell)
        if placed and ((poses[:placed, :2] - xy) ** 2).sum(1).min() < min_sep2:
            continue
        poses[placed, :2] = xy
        poses[placed, 2] = float(rng.uniform(-math.pi, math.pi))
        placed += 1
    return poses


def placement_radius_m(config: WorldConfig) -> float:
    """``passby`` placement: the cover radius less half a forward step (at least half the radius)."""
    cover, step = config.cover_radius_m, config.robot.forward_m
    return max(cover - step / 2, cover / 2)


def draw_targets(scene: Scene, reachable: np.ndarray, config: WorldConfig, rng: np.random.Generator) -> np.ndarray:
    """The target cells of an episode, (count, 2) (iy, ix), as :meth:`World.reset` draws them: by the
    placement of ``config``'s protocol (:func:`coverable_cells` under ``paper``, within
    :func:`placement_radius_m` of ``reachable`` under ``passby``)."""
    if config.rule.centre_placement:
        return sample_targets_on(scene, coverable_cells(reachable), config.targets.count, rng)
    return sample_targets(scene, reachable, config.targets.count, placement_radius_m(config), rng)


def coverable_cells(reachable: np.ndarray) -> np.ndarray:
    """(H, W) bool: where targets go under the ``paper`` protocol: the cells of the team's
    reachable region (where a robot centre may stand, by the world's collision rule) less its
    outermost cells (one cell, 8-connected), so that a robot can drive its centre over every target
    with room to line up its last move."""
    inner = ndimage.binary_erosion(reachable, structure=np.ones((3, 3), bool), border_value=0)
    return np.asarray(inner, dtype=bool)


def sample_targets_on(scene: Scene, cells_mask: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """Draw ``count`` distinct cells (iy, ix) of ``cells_mask`` uniformly."""
    if count == 0:
        return np.zeros((0, 2), dtype=np.int64)
    cells = np.argwhere(cells_mask & scene.free)
    if len(cells) < count:
        raise ConfigError(
            f"{scene.name}: only {len(cells)} coverable free cells for {count} targets; use fewer targets"
        )
    pick = rng.choice(len(cells), size=count, replace=False)
    return cells[np.sort(pick)]


def sample_targets(
    scene: Scene, reachable: np.ndarray, count: int, cover_radius_m: float, rng: np.random.Generator
) -> np.ndarray:
    """Draw ``count`` distinct free cells (iy, ix) that a robot on ``reachable`` can come within
    ``cover_radius_m`` of (centre to centre), uniformly."""
    if count == 0:
        return np.zeros((0, 2), dtype=np.int64)
    dist_cells = ndimage.distance_transform_edt(~reachable)
    coverable = scene.free & (np.asarray(dist_cells) * scene.cell_m <= cover_radius_m)
    cells = np.argwhere(coverable)
    if len(cells) < count:
        raise ConfigError(
            f"{scene.name}: only {len(cells)} coverable free cells for {count} targets; use fewer targets"
        )
    pick = rng.choice(len(cells), size=count, replace=False)
    return cells[np.sort(pick)]
