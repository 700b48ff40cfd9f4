"""Decision time of the goal planners: milliseconds per ``assign(obs)`` on real observations.

Drives :class:`areasearch.envs.goal.AreaSearchEnv` (4 robots, seed 0) with the greedy planner for one
episode per map, keeps every observation, then times each registered planner's ``assign`` over all
of them (``--repeats`` passes, the planner reset with the same seed each pass). Reports the mean,
median and worst time per decision, and the candidate count of the observations. Single process,
one thread.

    python benchmarks/bench_planners.py [--robots 4] [--repeats 3] [--maps robotathome_sarmis bormann_lab_ipa]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from areasearch.envs.goal import AreaSearchEnv
from areasearch.planners import PLANNERS, make_planner
from areasearch.sim.scene import load_scene


def collect(map_id: str, robots: int, seed: int) -> list[dict[str, np.ndarray]]:
    """Every observation of one episode driven by the greedy planner."""
    env = AreaSearchEnv(map=map_id, num_robots=robots, seed=seed)
    obs, _ = env.reset(seed=seed)
    driver = make_planner("greedy")
    driver.reset(np.random.default_rng(seed))
    seen = [obs]
    done = False
    while not done:
        obs, _, terminated, truncated, _ = env.step(driver.assign(obs))
        seen.append(obs)
        done = terminated or truncated
    return seen


def time_planner(name: str, observations: list[dict[str, np.ndarray]], repeats: int, seed: int) -> np.ndarray:
    """(repeats * len(observations),) seconds per assign call."""
    planner = make_planner(name)
    planner.reset(np.random.default_rng(seed))
    planner.assign(observations[0])  # warm up
    spent = []
    for _ in range(repeats):
        planner.reset(np.random.default_rng(seed))
        for obs in observations:
            t0 = time.perf_counter()
            planner.assign(obs)
            spent.append(time.perf_counter() - t0)
    return np.array(spent)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--maps", nargs="+", default=["robotathome_sarmis", "bormann_lab_ipa"])
    args = parser.parse_args()
    print(f"{'map':20} {'class':6} {'planner':11} {'mean':>8} {'median':>8} {'max':>8} {'decisions':>9} {'cands':>11}")
    for map_id in args.maps:
        observations = collect(map_id, args.robots, args.seed)
        counts = np.array([int(obs["candidate_mask"].sum()) for obs in observations])
        size = load_scene(map_id).size_class
        for name in PLANNERS:
            ms = 1e3 * time_planner(name, observations, args.repeats, args.seed)
            print(
                f"{map_id:20} {size:6} {name:11} {ms.mean():6.3f}ms {np.median(ms):6.3f}ms {ms.max():6.2f}ms "
                f"{len(observations):9d} {counts.mean():5.1f}/{counts.max():<5d}"
            )
    print(
        f"({args.robots} robots, observations of one greedy-driven episode per map, {args.repeats} passes; "
        "time per assign() call; cands = candidates per observation, mean/max)"
    )


if __name__ == "__main__":
    main()
