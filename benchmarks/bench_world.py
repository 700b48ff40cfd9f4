"""Throughput of the low-level loop: robot-steps per second, single process, one thread.

Measures :meth:`areasearch.sim.world.World.step` (motion, depth rendering for every robot, mapping,
target discovery and cover, metrics) and the PettingZoo ``ParallelEnv.step`` on top of it, with a
bounce-walk controller so the robots keep exploring. The controller's own time is not counted.

    python benchmarks/bench_world.py [--robots 4] [--steps 3000] [--maps robotathome_sarmis bormann_lab_ipa]
    python benchmarks/bench_world.py --compare-protocols   # World.step under passby and paper, interleaved
    python benchmarks/bench_world.py --compare-realism     # World.step under each imperfection, interleaved

``--compare-protocols`` times ``World.step`` under the ``passby`` cover rule (the end-of-step check
of earlier releases) and the ``paper`` rule (the swept-segment check) alternately in one process,
same maps, same walk, and prints the ratio: the cost of the swept check on a shared, noisy machine.

``--compare-realism`` times ``World.step`` in the perfect world and under each imperfection
(:data:`REALISM_CONDITIONS`: limited communication by a disc or by signal strength, which gives every
robot its own map; log-odds occupancy; the realism presets), alternately in one process, same maps,
same walk, and prints each one's rate over the perfect world's.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

import areasearch
from areasearch.config import WorldConfig, realism_config
from areasearch.sim.actions import bounce_walk
from areasearch.sim.scene import load_scene
from areasearch.sim.world import World

REALISM_CONDITIONS: dict[str, tuple[str, dict[str, object]]] = {
    "none": ("none", {}),
    "comm disc 5 m": ("none", {"comm.model": "disc", "comm.range_m": 5.0}),
    "comm signal": ("none", {"comm.model": "signal"}),
    "log-odds mapping": ("none", {"mapping.occupancy": "log_odds"}),
    "preset low": ("low", {}),
    "preset medium": ("medium", {}),
    "preset high": ("high", {}),
}
"""The worlds ``--compare-realism`` times: (realism preset, settings over it)."""


def bench_world(
    map_id: str, robots: int, steps: int, seed: int = 0, protocol: str = "paper", config: WorldConfig | None = None
) -> float:
    scene = load_scene(map_id)
    base = WorldConfig() if config is None else config
    world = World(dataclasses.replace(base, num_robots=robots, max_steps=steps, protocol=protocol))
    rng = np.random.default_rng(seed)
    world.reset(scene, rng)
    world.step(np.zeros(robots, dtype=np.int64))  # compile / warm up
    collided = np.zeros(robots, dtype=bool)
    turning = np.zeros(robots, dtype=np.int64)
    spent = 0.0
    for _ in range(steps - 1):
        actions = bounce_walk(collided, turning, rng)
        t0 = time.perf_counter()
        collided = world.step(actions).collided
        spent += time.perf_counter() - t0
    return robots * (steps - 1) / spent


def bench_env(map_id: str, robots: int, steps: int, seed: int = 0) -> float:
    env = areasearch.parallel_env(map=map_id, num_robots=robots, seed=seed, max_steps=steps + 1)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    collided = np.zeros(robots, dtype=bool)
    turning = np.zeros(robots, dtype=np.int64)
    spent = 0.0
    for _ in range(steps):
        acts = bounce_walk(collided, turning, rng)
        actions = {agent: int(a) for agent, a in zip(env.agents, acts, strict=True)}
        t0 = time.perf_counter()
        _, _, _, _, infos = env.step(actions)
        spent += time.perf_counter() - t0
        collided = np.array([infos[a]["collided"] for a in env.possible_agents])
    return robots * steps / spent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--maps", nargs="+", default=["robotathome_sarmis", "bormann_lab_ipa"])
    parser.add_argument("--repeats", type=int, default=3, help="best of this many runs")
    parser.add_argument("--compare-protocols", action="store_true", help="World.step under passby vs paper")
    parser.add_argument("--compare-realism", action="store_true", help="World.step under each imperfection")
    args = parser.parse_args()
    if args.compare_protocols:
        compare_protocols(args)
        return
    if args.compare_realism:
        compare_realism(args)
        return
    print(f"{'map':24} {'class':7} {'cells':>10} {'World.step':>18} {'ParallelEnv.step':>18}")
    for map_id in args.maps:
        scene = load_scene(map_id)
        w = max(bench_world(map_id, args.robots, args.steps) for _ in range(args.repeats))
        e = max(bench_env(map_id, args.robots, args.steps) for _ in range(args.repeats))
        cells = f"{scene.shape[1]}x{scene.shape[0]}"
        print(f"{map_id:24} {scene.size_class:7} {cells:>10} {w:12,.0f} r-st/s {e:12,.0f} r-st/s")
    print(f"({args.robots} robots, {args.steps} steps, robot-steps per second, best of {args.repeats})")


def interleaved(args: argparse.Namespace, map_id: str, variants: dict[str, dict[str, Any]]) -> dict[str, float]:
    """The best ``World.step`` rate on ``map_id`` of each variant (``bench_world`` keywords), the variants
    played in turn ``args.repeats`` times, so that load changes hit all alike."""
    best = dict.fromkeys(variants, 0.0)
    for _ in range(args.repeats):
        for name, keywords in variants.items():
            best[name] = max(best[name], bench_world(map_id, args.robots, args.steps, **keywords))
    return best


def compare_protocols(args: argparse.Namespace) -> None:
    print(f"{'map':24} {'passby':>16} {'paper':>16} {'paper / passby':>15}")
    for map_id in args.maps:
        best = interleaved(args, map_id, {"passby": {"protocol": "passby"}, "paper": {"protocol": "paper"}})
        ratio = best["paper"] / best["passby"]
        print(f"{map_id:24} {best['passby']:9,.0f} r-st/s {best['paper']:9,.0f} r-st/s {ratio:14.3f}")
    print(f"({args.robots} robots, {args.steps} steps, World.step robot-steps per second, best of {args.repeats})")


def compare_realism(args: argparse.Namespace) -> None:
    worlds = {
        name: {"config": realism_config(preset, settings).world}
        for name, (preset, settings) in REALISM_CONDITIONS.items()
    }
    print(f"{'map':24} {'world':18} {'World.step':>16} {'/ none':>7}")
    for map_id in args.maps:
        best = interleaved(args, map_id, worlds)
        for name, rate in best.items():
            print(f"{map_id:24} {name:18} {rate:9,.0f} r-st/s {rate / best['none']:7.3f}")
    print(f"({args.robots} robots, {args.steps} steps, World.step robot-steps per second, best of {args.repeats})")


if __name__ == "__main__":
    main()
