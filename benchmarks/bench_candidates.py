"""Cost of one decision's candidate goals: extraction plus all robot-candidate geodesic distances.

Drives a world with the bounce-walk controller and, at several points of the episode, times
:func:`areasearch.planning.candidates.extract_candidates` on the merged map (best of ``--repeats``), split
into the distance part (:func:`areasearch.planning.geodesic.distances_to` on the same inputs the extraction
builds) and the rest. Single process, one thread.

    python benchmarks/bench_candidates.py [--robots 4] [--at 200 800 1600] [--maps robotathome_sarmis bormann_lab_ipa]
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from areasearch.config import WorldConfig
from areasearch.planning import candidates as cand
from areasearch.sim.actions import bounce_walk
from areasearch.sim.scene import load_scene
from areasearch.sim.world import World


def time_decision(world: World, repeats: int) -> tuple[float, float, cand.Candidates]:
    """(total ms, distance ms, candidates) of the fastest of ``repeats`` extractions.

    The distance part is timed by wrapping the ``distances_to`` that the candidates module calls.
    """
    distances_to = cand.distances_to
    spent: list[float] = []

    def timed(*args: Any, **kwargs: Any) -> np.ndarray:
        t0 = time.perf_counter()
        out = distances_to(*args, **kwargs)
        spent.append(time.perf_counter() - t0)
        return out

    runs = []
    cand.distances_to = timed
    try:
        for _ in range(repeats):
            t0 = time.perf_counter()
            found = cand.extract_from_world(world)
            runs.append((time.perf_counter() - t0, spent[-1]))
    finally:
        cand.distances_to = distances_to
    total, dist = min(runs)
    return 1e3 * total, 1e3 * dist, found


def bench_map(map_id: str, robots: int, checkpoints: list[int], repeats: int, seed: int = 0) -> None:
    scene = load_scene(map_id)
    world = World(WorldConfig(num_robots=robots, max_steps=max(checkpoints) + 1))
    rng = np.random.default_rng(seed)
    world.reset(scene, rng)
    cand.extract_from_world(world)  # compile / warm up
    collided = np.zeros(robots, dtype=bool)
    turning = np.zeros(robots, dtype=np.int64)
    cells = f"{scene.shape[1]}x{scene.shape[0]}"
    for step in range(1, max(checkpoints) + 1):
        collided = world.step(bounce_walk(collided, turning, rng)).collided
        if step not in checkpoints:
            continue
        total, dist, found = time_decision(world, repeats)
        n_front = int(found.is_frontier.sum())
        print(
            f"{map_id:20} {cells:>8} {step:>5} {100 * world.metrics.explored_fraction:6.1f}% "
            f"{len(found):>5} {n_front:>5} {len(found) - n_front:>5} {total:9.2f} {total - dist:9.2f} {dist:9.2f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--at", type=int, nargs="+", default=[200, 800, 1600], help="steps at which to time")
    parser.add_argument("--maps", nargs="+", default=["robotathome_sarmis", "bormann_lab_ipa"])
    parser.add_argument("--repeats", type=int, default=20, help="best of this many runs")
    args = parser.parse_args()
    print(
        f"{'map':20} {'cells':>8} {'step':>5} {'expl':>7} {'cand':>5} {'front':>5} {'targ':>5} "
        f"{'total ms':>9} {'extract':>9} {'distance':>9}"
    )
    for map_id in args.maps:
        bench_map(map_id, args.robots, sorted(args.at), args.repeats)
    print(
        f"({args.robots} robots, bounce walk, time per decision = best of {args.repeats}; extract = total - distance)"
    )


if __name__ == "__main__":
    main()
