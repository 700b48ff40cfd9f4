"""Training throughput: decisions/s and robot-steps/s of a few PPO iterations, against the bare environment.

Runs :func:`areasearch.training.train.train` on a training config (default ``configs/dahgnn.toml``) into a
temporary folder for ``--warmup`` + ``--iterations`` iterations with ``--workers`` worker processes,
drops the warm-up rows (numba and PyTorch warm-up) and reads the ``perf/`` columns of the run's
``progress.csv``; then steps the PettingZoo ``ParallelEnv`` on one core (``--robots`` robots, random
actions, the medium map ``--map``) for ``--env-steps`` steps. Prints decisions/s, robot-steps/s,
the rollout's and the update's share of an iteration, and the ratio that does not depend on the
machine: (training robot-steps/s per worker) / (ParallelEnv robot-steps/s on one core).

    python benchmarks/bench_train.py [--config configs/dahgnn.toml] [--workers 2] [--warmup 1]
        [--iterations 3] [--robots 4] [--map robotathome_sarmis] [--env-steps 20000] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

import areasearch
from areasearch.training.train import load_config, train


def training_rates(
    config_path: str, workers: int, warmup: int, iterations: int, overrides: dict[str, Any] | None = None
) -> dict[str, float]:
    """Mean ``perf/`` figures of ``iterations`` training iterations after ``warmup`` ones."""
    config = load_config(config_path, overrides)
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "run"
        train(config, out, workers=workers, log=None, progress=None, iterations=warmup + iterations)
        with (out / "progress.csv").open() as f:
            rows = list(csv.DictReader(f))[warmup:]
    if not rows:
        raise SystemExit("no iteration after the warm-up: raise --iterations")

    def mean(key: str) -> float:
        return statistics.fmean(float(r[key]) for r in rows)

    rollout, update = mean("perf/rollout_s"), mean("perf/update_s")
    return {
        "decisions_per_s": mean("perf/decisions_per_s"),
        "robot_steps_per_s": mean("perf/robot_steps_per_s"),
        "rollout_share": rollout / (rollout + update),
        "iterations": float(len(rows)),
    }


def env_rate(map_id: str, robots: int, steps: int, seed: int = 0) -> float:
    """Robot-steps per second of the PettingZoo ParallelEnv with random actions, one process."""
    env = areasearch.parallel_env(map=map_id, num_robots=robots, seed=seed)
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    env.step({a: int(rng.integers(4)) for a in env.agents})  # warm-up
    done, t0 = 0, time.perf_counter()
    while done < steps:
        if not env.agents:
            env.reset(seed=seed + done)
        env.step({a: int(rng.integers(4)) for a in env.agents})
        done += 1
    return steps * robots / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/dahgnn.toml")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=1)
    parser.add_argument("--iterations", type=int, default=3)
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--map", default="robotathome_sarmis")
    parser.add_argument("--env-steps", type=int, default=20000)
    parser.add_argument(
        "--set", nargs="+", default=[], metavar="KEY=VALUE", help="overrides, e.g. rollout.lockstep=2 ppo.threads=2"
    )
    args = parser.parse_args()
    overrides = {key: json.loads(value) for key, _, value in (item.partition("=") for item in args.set)}
    rates = training_rates(args.config, args.workers, args.warmup, args.iterations, overrides)
    bare = env_rate(args.map, args.robots, args.env_steps)
    ratio = rates["robot_steps_per_s"] / args.workers / bare
    print(
        f"config {args.config} {' '.join(args.set)}, {args.workers} workers, "
        f"{rates['iterations']:.0f} iterations after {args.warmup}"
    )
    print(f"training: {rates['decisions_per_s']:.1f} decisions/s, {rates['robot_steps_per_s']:,.0f} robot-steps/s")
    share = 100 * rates["rollout_share"]
    print(f"          rollout {share:.0f} % of an iteration, update {100 - share:.0f} %")
    print(f"ParallelEnv ({args.robots} robots, random actions, {args.map}, one core): {bare:,.0f} robot-steps/s")
    print(f"ratio (training robot-steps/s per worker / ParallelEnv): {ratio:.3f}")


if __name__ == "__main__":
    main()
