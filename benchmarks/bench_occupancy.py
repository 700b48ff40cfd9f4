"""Cost of the mapper's occupancy models: :meth:`Mapper.integrate <areasearch.sim.mapper.Mapper.integrate>`
with sticky occupancy against log-odds occupancy (:mod:`areasearch.sim.occupancy`), on the same frames.

The frames are those of a seeded episode under depth noise (``noise.depth``, default 0.02): 3 robots
driven by ``bounce_walk`` on ``--map`` for ``--steps`` steps, each step's depth images (R, H, W) and
believed poses recorded. Each model's mapper then fuses the whole sequence, ``--repeats`` times (the first
run compiles and is not counted); the time per call (one step's R images) is the median over the repeats.
Single process, one thread.

    python benchmarks/bench_occupancy.py [--map robotathome_sarmis] [--steps 300] [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from areasearch.config import MappingConfig, WorldConfig, override
from areasearch.sim.actions import bounce_walk
from areasearch.sim.mapper import Mapper
from areasearch.sim.scene import load_scene
from areasearch.sim.world import World


def record(map_id: str, steps: int, depth_noise: float, seed: int) -> tuple[World, list[tuple[np.ndarray, np.ndarray]]]:
    """A seeded episode's frames: (depth (R, H, W), believed poses (R, 3)) of every step."""
    world = World(override(WorldConfig(), **{"noise.depth": depth_noise}))
    rng = np.random.default_rng(seed)
    world.reset(load_scene(map_id), rng)
    turning = np.zeros(world.config.num_robots, dtype=np.int64)
    collided = np.zeros(world.config.num_robots, dtype=bool)
    frames = []
    for _ in range(steps):
        collided = world.step(bounce_walk(collided, turning, rng)).collided
        frames.append((world.depth.copy(), world.believed_poses.copy()))
    return world, frames


def time_model(world: World, frames: list[tuple[np.ndarray, np.ndarray]], model: str, repeats: int) -> float:
    """Median seconds per :meth:`Mapper.integrate` call of ``model`` over the frames."""
    scene = world.scene
    assert scene is not None
    mapper = Mapper(scene.shape, scene.cell_m, scene.origin_xy, occupancy=MappingConfig(occupancy=model))  # type: ignore[arg-type]
    times = []
    for i in range(repeats + 1):
        mapper.reset()
        t0 = time.perf_counter()
        for depth, poses in frames:
            mapper.integrate(depth, world.config.camera, poses)
        if i:
            times.append((time.perf_counter() - t0) / len(frames))
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default="robotathome_sarmis")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--depth-noise", type=float, default=0.02)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    world, frames = record(args.map, args.steps, args.depth_noise, args.seed)
    sticky = time_model(world, frames, "sticky", args.repeats)
    log_odds = time_model(world, frames, "log_odds", args.repeats)
    print(f"{args.map}, {world.config.num_robots} robots, {args.steps} steps, noise.depth {args.depth_noise}")
    print(f"sticky   integrate: {sticky * 1e6:8.1f} us per step")
    print(f"log_odds integrate: {log_odds * 1e6:8.1f} us per step  ({log_odds / sticky:.2f} x sticky)")


if __name__ == "__main__":
    main()
