"""Throughput of the high-level loop: decisions with the trivial nearest-candidate choice.

Runs :class:`areasearch.envs.goal.AreaSearchEnv` (4 robots, one decision per 40 steps, the 3600-step
horizon) with :func:`areasearch.envs.goal.nearest_candidate` and reports robot-steps per second of
the whole loop, and where the time goes: the world (sensing, mapping, targets), the FMM action
planner (path following and re-planning, per robot-step), and the decision (candidates with their
FMM distances, observation). Single process, one thread.

    python benchmarks/bench_goal_env.py [--robots 4] [--episodes 2] [--maps robotathome_sarmis bormann_lab_ipa]
        [--repeats 1] [--size-class small|medium|large] [--realism none|low|medium|high]

``--size-class C`` plays every bundled map of that size class instead of ``--maps`` and ends with
the mean over the maps and the slowest map.

``--realism P`` plays the episodes under a realism preset (noise, detection, limited communication):
where an imperfect world's time goes.

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

from areasearch.config import REALISM_NAMES
from areasearch.envs.goal import AreaSearchEnv, decide, nearest_candidate
from areasearch.sim.scene import bundled_index, load_scene


def timed(store: dict[str, float], key: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            store[key] += time.perf_counter() - t0

    return wrapper


def run(map_id: str, robots: int, seed: int, realism: str = "none") -> dict[str, float]:
    env = AreaSearchEnv(map=map_id, num_robots=robots, seed=seed, realism=realism)
    obs, _ = env.reset(seed=seed)
    env.step(nearest_candidate(obs))  # compile / warm up
    env.reset(seed=seed)
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
        _, _, terminated, truncated, info = env.step(decide(env, nearest_candidate))  # per group if cut off
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
    parser.add_argument("--size-class", choices=("small", "medium", "large"), help="every bundled map of this class")
    parser.add_argument("--realism", choices=REALISM_NAMES, default="none", help="realism preset of the episodes")
    args = parser.parse_args()
    if args.size_class:
        args.maps = [e["id"] for e in bundled_index() if e["size_class"] == args.size_class]
    rates: dict[str, float] = {}
    print(
        f"{'map':26} {'class':6} {'r-steps/s':>9} {'world':>8} {'planner':>8} {'decision':>9} "
        f"{'cands':>7} {'replans':>8} {'explored':>8} {'covered':>8}"
    )
    for map_id in args.maps:
        passes = []
        for _ in range(max(1, args.repeats)):
            spent: dict[str, float] = defaultdict(float)
            for seed in range(args.episodes):
                for key, value in run(map_id, args.robots, seed, args.realism).items():
                    spent[key] += value
            passes.append(spent)
        total = min(passes, key=lambda p: p["total"])
        steps = total["robot_steps"]
        us = 1e6 / steps
        rates[map_id] = steps / total["total"]
        print(
            f"{map_id:26} {load_scene(map_id).size_class:6} {steps / total['total']:9,.0f} "
            f"{total['world'] * us:6.1f}us {total['planner'] * us:6.1f}us "
            f"{(total['candidates'] + total['observation']) * 1e3 / total['decisions']:7.2f}ms "
            f"{total['candidates'] * 1e3 / total['decisions']:5.2f}ms {total['replans'] / args.episodes:8.0f} "
            f"{total['explored_pct'] / args.episodes:7.1f}% {total['covered_pct'] / args.episodes:7.1f}%"
        )
    print(
        f"({args.robots} robots, {args.episodes} episodes per map, realism {args.realism}, "
        f"fastest of {max(1, args.repeats)} passes; "
        "world and planner per robot-step, "
        "decision = candidates + observation per decision, cands = candidates + FMM distances alone, "
        "replans per episode)"
    )
    if len(rates) > 1:
        slowest = min(rates, key=rates.__getitem__)
        print(
            f"{len(rates)} maps: whole loop {sum(rates.values()) / len(rates):,.0f} robot-steps/s on average, "
            f"slowest {rates[slowest]:,.0f} ({slowest})"
        )


if __name__ == "__main__":
    main()
