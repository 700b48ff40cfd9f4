"""Can Explo % reach 100 % on every map? The share of each scene's reachable floor a robot's camera sees.

For every map it puts the robot's depth camera at every ``--stride``-th cell of the team's region
(``Scene.reachable``: where a robot centre may stand) facing ``--headings`` directions, fuses all
the images with the world's own mapper and prints the share of the scene's reachable floor
(``Scene.reachable_floor``, Explo %'s denominator) that became explored: 100.00 means a team that
went everywhere would reach Explo % 100. The cells it never saw are listed by count; ``--png`` draws
them.

    python scripts/check_explorable.py [MAP ...] [--stride 2] [--headings 12] [--png DIR]

MAP: bundled ids, ROS YAML files or folders, as for ``areasearch eval --maps`` (default: every
bundled map). Exit status 1 when a map is below ``--min-pct`` (default 100).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from areasearch.config import CameraConfig, RobotConfig
from areasearch.harness.evaluate import resolve_maps
from areasearch.sim.depth import render_depth
from areasearch.sim.mapper import Mapper
from areasearch.sim.scene import Scene, load_scene


def observed_floor(scene: Scene, stride: int = 2, headings: int = 12, batch: int = 512) -> np.ndarray:
    """(H, W) bool: the cells of ``scene.reachable_floor()`` the camera sees from some pose of the
    team's region (every ``stride``-th cell in both axes, ``headings`` yaws)."""
    robot, camera = RobotConfig(), CameraConfig()
    cells = np.argwhere(scene.reachable(robot.radius_m))
    cells = cells[(cells[:, 0] % stride == 0) & (cells[:, 1] % stride == 0)]
    xy = scene.cell_to_world(cells)
    yaws = np.arange(headings) * (2 * math.pi / headings) - math.pi
    poses = np.concatenate([np.column_stack([xy, np.full(len(xy), yaw)]) for yaw in yaws])
    mapper = Mapper(scene.shape, scene.cell_m, scene.origin_xy, obstacle_top_m=robot.height_m)
    h_max = float(scene.height_m.max())
    for start in range(0, len(poses), batch):
        chunk = poses[start : start + batch]
        depth = render_depth(scene.height_m, scene.cell_m, scene.origin_xy, chunk, camera, h_max=h_max)
        mapper.integrate(depth, camera, chunk)
    return mapper.explored & scene.reachable_floor(robot.radius_m)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("maps", nargs="*", default=["bundled"])
    parser.add_argument("--stride", type=int, default=2, help="every this-many-th cell of the region (default 2)")
    parser.add_argument("--headings", type=int, default=12, help="camera yaws per position (default 12)")
    parser.add_argument("--min-pct", type=float, default=100.0, help="exit 1 when a map is below this (default 100)")
    parser.add_argument("--png", type=Path, help="draw the unseen cells of each map below 100 %% into this folder")
    args = parser.parse_args(argv)
    entries = resolve_maps(args.maps)
    print("| map | size | reachable floor (m²) | unreachable floor (m²) | seen (%) | unseen cells |")
    print("|---|---|---:|---:|---:|---:|")
    worst = 100.0
    for entry in entries:
        scene = load_scene(entry.spec)
        floor = scene.reachable_floor()
        seen = observed_floor(scene, args.stride, args.headings)
        pct = 100.0 * seen.sum() / floor.sum()
        worst = min(worst, pct)
        unreachable = (scene.free & ~floor).sum() * scene.cell_m**2
        print(
            f"| {entry.id} | {entry.size_class} | {scene.reachable_area_m2():.2f} | {unreachable:.2f} | "
            f"{math.floor(pct * 100) / 100:.2f} | {int((floor & ~seen).sum())} |",
            flush=True,
        )
        if args.png and pct < 100.0:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt

            args.png.mkdir(parents=True, exist_ok=True)
            image = np.zeros((*scene.shape, 3))
            image[scene.free] = (0.8, 0.8, 0.8)
            image[floor] = (1, 1, 1)
            image[floor & ~seen] = (1, 0, 0)
            plt.imsave(args.png / f"{entry.id}.png", image[::-1])
    return 0 if worst >= args.min_pct else 1


if __name__ == "__main__":
    sys.exit(main())
