"""Latency of one :func:`areasearch.service.assign.assign_goals` call: 5 robots on a large map, per method.

The partial maps are what a team of 5 has mapped of the largest bundled map
(``bormann_office_g_rooms3``, 1821 x 1826 cells of 5 cm, 899 m² of floor) after ``--decisions``
Greedy decisions of the simulator (early: little known, few frontiers; later: more of both). Each is
handed to ``assign_goals`` with the robots' poses and the targets seen so far, as a robot stack would
hand over its SLAM map: the call does everything (footprint checks, candidates and FMM distances on
the given map, the observation, the planner, one path per robot). Times per call: the median and
the worst of ``--repeats`` calls with the map in memory (planner built once, as a long-running node
would), and the median when the map is read from its ROS YAML + PNG on every call (as
``areasearch assign`` does). Single process, one thread (numba and PyTorch).

    python benchmarks/bench_assign.py [--map bormann_office_g_rooms3] [--decisions 5 25] [--repeats 10]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import torch

from areasearch.config import search_config
from areasearch.envs.goal import AreaSearchEnv
from areasearch.harness.evaluate import planner_rng
from areasearch.planners import PLANNERS, make_planner
from areasearch.service.assign import OccupancyMap, assign_goals, build_decision, save_occupancy_yaml


def snapshots(
    map_id: str, robots: int, decisions: list[int], seed: int
) -> list[tuple[int, OccupancyMap, np.ndarray, np.ndarray]]:
    """(decision, partial map, (R, 3) poses, (T, 2) open targets) after each of ``decisions``."""
    env = AreaSearchEnv(map=map_id, num_robots=robots, seed=seed)
    obs, _ = env.reset(seed=seed)
    driver = make_planner("greedy")
    driver.reset(planner_rng(seed))
    world = env.world
    out = []
    for k in range(1, max(decisions) + 1):
        obs, *_ = env.step(driver.assign(obs))
        if k in decisions:
            assert world.scene is not None and world.mapper is not None
            mapper, scene = world.mapper, world.scene
            grid = OccupancyMap(
                mapper.explored & ~mapper.occupied, mapper.occupied.copy(), scene.cell_m, scene.origin_xy
            )
            targets = world.targets_xy[np.flatnonzero(world.discovered & ~world.covered)]
            out.append((k, grid, world.poses.copy(), targets.copy()))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default="bormann_office_g_rooms3")
    parser.add_argument("--robots", type=int, default=5)
    parser.add_argument("--decisions", type=int, nargs="+", default=[5, 25])
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--methods", nargs="+", default=list(PLANNERS))
    parser.add_argument(
        "--distance-cells",
        type=float,
        nargs="+",
        default=[0.0],
        metavar="M",
        help="candidates.distance_cell_m settings, timed alternating call by call (e.g. 0 0.1)",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    planners = {name: make_planner(name) for name in args.methods}
    configs = {m: search_config({"candidates.distance_cell_m": m}) for m in args.distance_cells}
    print(
        f"{'map':24} {'steps':>6} {'known':>7} {'cands':>5} {'method':17} {'cell m':>6} {'median':>9} {'max':>9} "
        f"{'from YAML':>10}"
    )
    with tempfile.TemporaryDirectory() as folder:
        for k, grid, poses, targets in snapshots(args.map, args.robots, args.decisions, args.seed):
            path = save_occupancy_yaml(grid, Path(folder) / f"{args.map}_{k}.yaml")
            known = grid.explored.sum() * grid.cell_m**2
            cands = len(build_decision(grid, poses, targets).candidates)
            for name, planner in planners.items():
                spent: dict[float, list[float]] = {m: [] for m in configs}
                from_file: dict[float, list[float]] = {m: [] for m in configs}
                for config in configs.values():
                    assign_goals(grid, poses, planner, targets, config=config)  # warm up (numba, first torch call)
                for _ in range(args.repeats):
                    for m, config in configs.items():
                        t0 = time.perf_counter()
                        assign_goals(grid, poses, planner, targets, config=config)
                        spent[m].append(time.perf_counter() - t0)
                for _ in range(max(3, args.repeats // 3)):
                    for m, config in configs.items():
                        t0 = time.perf_counter()
                        assign_goals(path, poses, planner, targets, config=config)
                        from_file[m].append(time.perf_counter() - t0)
                for m in configs:
                    ms, file_ms = 1e3 * np.array(spent[m]), 1e3 * np.array(from_file[m])
                    print(
                        f"{args.map:24} {k * 40:6d} {known:6.0f}m² {cands:5d} {name:17} {m:6.2f} "
                        f"{np.median(ms):7.1f}ms {ms.max():7.1f}ms {np.median(file_ms):8.1f}ms"
                    )
    print(
        f"({args.robots} robots, 'steps' = primitive steps of Greedy exploration before the snapshot, 'known' = "
        "mapped area, 'cands' = candidate goals; time of one assign_goals call, one thread)"
    )


if __name__ == "__main__":
    main()
