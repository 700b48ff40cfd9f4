"""Soak test (not in CI): many episodes across methods in one process, memory at start and end.

Plays ``--episodes`` (1,000) episodes one after another in this process, as a worker of
``areasearch eval`` does (:func:`areasearch.harness.evaluate.run_episode`: a new environment and planner per
episode), cycling through every registered planner (11, classical and learned) and 9 bundled maps (3
small, 3 medium, 3 large, evenly spaced by id; teams of 3, 4 and 5 robots, one size per map), each
episode with its own seed. 9 and 11 have no common factor, so the first 99 episodes play every
(map, method) pair once: whatever the run holds at its peak, the warm-up has held already. Episodes
are cut at ``--max-steps`` (400 primitive steps, 10 decisions, by default) to keep the run to minutes;
what a leak would accumulate (environments, worlds, mappers, FMM buffers, networks, numba and
PyTorch state) is built and dropped once per episode all the same.

Reports the resident set size (RSS, now and peak) at the start, after the first ``--warmup`` (100)
episodes, every ``--every`` episodes and at the end, and exits non-zero when the peak RSS grew by
more than ``--tolerance-mb`` after the warm-up (the first episodes fill caches: numba kernels, maps,
PyTorch's allocator). Single thread.

    python benchmarks/soak.py [--episodes 1000] [--max-steps 400] [--out results/soak.json]
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import resource
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import torch

from areasearch.harness.evaluate import Episode, episode_seed, resolve_maps, run_episode
from areasearch.planners import PLANNERS


def rss_mb() -> tuple[float, float]:
    """(current, peak) resident set size of this process, MiB."""
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    current = pages * os.sysconf("SC_PAGE_SIZE") / 2**20
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    return current, peak


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--max-steps", type=int, default=400)
    parser.add_argument("--maps-per-size", type=int, default=3)
    parser.add_argument("--warmup", type=int, default=100)
    parser.add_argument("--every", type=int, default=100)
    parser.add_argument("--tolerance-mb", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None, help="write the report here as JSON")
    args = parser.parse_args()
    torch.set_num_threads(1)

    methods = list(PLANNERS)
    maps = resolve_maps(["bundled"], per_size=args.maps_per_size)
    teams = (3, 4, 5)  # map k plays with teams[k % 3]
    log: list[dict[str, float]] = []

    def record(done: int, t0: float) -> None:
        gc.collect()
        current, peak = rss_mb()
        log.append({"episodes": done, "elapsed_s": round(time.perf_counter() - t0, 1), "rss_mb": round(current, 1),
                    "peak_rss_mb": round(peak, 1)})  # fmt: skip
        print(
            f"{done:5d} episodes  {log[-1]['elapsed_s']:8.1f} s  RSS {current:7.1f} MiB  peak {peak:7.1f} MiB",
            flush=True,
        )

    t0 = time.perf_counter()
    record(0, t0)
    for i in range(args.episodes):
        entry = maps[i % len(maps)]
        robots = teams[(i % len(maps)) % len(teams)]
        method = methods[i % len(methods)]
        seed = episode_seed(args.seed, entry.id, robots, i)
        run_episode(Episode(method, entry, robots, i, seed, args.max_steps))
        done = i + 1
        if done == args.warmup or done % args.every == 0 or done == args.episodes:
            if not log or log[-1]["episodes"] != done:
                record(done, t0)
    after_warmup = next(r for r in log if r["episodes"] >= min(args.warmup, args.episodes))
    growth = log[-1]["peak_rss_mb"] - after_warmup["peak_rss_mb"]
    report = {
        "episodes": args.episodes,
        "max_steps": args.max_steps,
        "methods": methods,
        "maps": [e.id for e in maps],
        "teams": list(teams),
        "start": log[0],
        "after_warmup": after_warmup,
        "end": log[-1],
        "peak_growth_after_warmup_mb": round(growth, 1),
        "tolerance_mb": args.tolerance_mb,
        "log": log,
    }
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.out.with_name(f".{args.out.name}.tmp")
        tmp.write_text(json.dumps(report, indent=2) + "\n")
        tmp.replace(args.out)
    verdict = "OK" if growth <= args.tolerance_mb else "GREW"
    print(
        f"{verdict}: peak RSS {after_warmup['peak_rss_mb']:.1f} MiB after {after_warmup['episodes']} episodes, "
        f"{log[-1]['peak_rss_mb']:.1f} MiB after {args.episodes} ({growth:+.1f} MiB, tolerance {args.tolerance_mb}); "
        f"{len(maps)} maps x {len(methods)} methods x teams {teams}, {args.max_steps} steps, "
        f"{log[-1]['elapsed_s'] / 60:.1f} min"
    )
    return 0 if verdict == "OK" else 1


if __name__ == "__main__":
    raise SystemExit(main())
