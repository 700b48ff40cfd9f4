"""Throughput of the high-level loop: decisions with the trivial nearest-candidate choice.

Runs :class:`areasearch.goal_env.AreaSearchEnv` (4 robots, one decision per 40 steps, the 3600-step
horizon) with :func:`areasearch.goal_env.nearest_candidate` and reports robot-steps per second of
the whole loop, and where the time goes: the world (sensing, mapping, targets), the FMM action
planner (path following and re-planning, per robot-step), and the decision (candidates with their
FMM distances, observation). Single process, one thread.

    python benchmarks/bench_goal_env.py [--robots 4] [--episodes 2] [--maps robotathome_sarmis bormann_lab_ipa]
        [--repeats 1]

``--repeats N`` plays the episodes N times per map and reports the fastest pass (on a machine other
jobs share, the least disturbed one).
"""

from __future__ import annotations

import argparse
import os
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from areasearch.goal_env import AreaSearchEnv, nearest_candidate
from areasearch.scene import load_scene


def timed(store: dict[str, float], key: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            store[key] += time.perf_counter() - t0

    return wrapper


def run(map_id: str, robots: int, seed: int) -> dict[str, float]:
    env = AreaSearchEnv(map=map_id, num_robots=robots, seed=seed)
    obs, _ = env.reset(seed=seed)
    env.step(nearest_candidate(obs))  # compile / warm up
    obs, _ = env.reset(seed=seed)
    spent: dict[str, float] = defaultdict(float)
    env.world.step = timed(spent, "world", env.world.step)  # type: ignore[method-assign]
    env._refresh_candidates = timed(spent, "candidates", env._refresh_candidates)  # type: ignore[method-assign]
    env._observation = timed(spent, "observation", env._observation)  # type: ignore[method-assign]
    assert env.planner is not None
    env.planner.act = timed(spent, "planner", env.planner.act)  # type: ignore[method-assign]
    decisions = 0
    t0 = time.perf_counter()
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(nearest_candidate(obs))
        decisions += 1
        done = terminated or truncated
    spent["total"] = time.perf_counter() - t0
    spent["robot_steps"] = info["steps"] * robots
    spent["decisions"] = decisions
    spent["replans"] = env.planner.replans
    spent["explored_pct"] = info["explored_pct"]
    spent["covered_pct"] = info["covered_pct"]
    return spent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--maps", nargs="+", default=["robotathome_sarmis", "bormann_lab_ipa"])
    parser.add_argument("--repeats", type=int, default=1, help="report the fastest of this many passes")
    args = parser.parse_args()
    print(
        f"{'map':20} {'class':6} {'r-steps/s':>9} {'world':>8} {'planner':>8} {'decision':>9} "
        f"{'cands':>7} {'replans':>8} {'explored':>8} {'covered':>8}"
    )
    for map_id in args.maps:
        passes = []
        for _ in range(max(1, args.repeats)):
            spent: dict[str, float] = defaultdict(float)
            for seed in range(args.episodes):
                for key, value in run(map_id, args.robots, seed).items():
                    spent[key] += value
            passes.append(spent)
        total = min(passes, key=lambda p: p["total"])
        steps = total["robot_steps"]
        us = 1e6 / steps
        print(
            f"{map_id:20} {load_scene(map_id).size_class:6} {steps / total['total']:9,.0f} "
            f"{total['world'] * us:6.1f}us {total['planner'] * us:6.1f}us "
            f"{(total['candidates'] + total['observation']) * 1e3 / total['decisions']:7.2f}ms "
            f"{total['candidates'] * 1e3 / total['decisions']:5.2f}ms {total['replans'] / args.episodes:8.0f} "
            f"{total['explored_pct'] / args.episodes:7.1f}% {total['covered_pct'] / args.episodes:7.1f}%"
        )
    print(
        f"({args.robots} robots, {args.episodes} episodes per map, fastest of {max(1, args.repeats)} passes; "
        "world and planner per robot-step, "
        "decision = candidates + observation per decision, cands = candidates + FMM distances alone, "
        "replans per episode)"
    )


if __name__ == "__main__":
    main()
