"""Wall time of the paper's test protocol with the evaluation harness (``areasearch eval``).

The protocol of DA-HGNN's Tables 3-5: 3 size classes x team sizes 3, 4, 5 x 6 methods (greedy,
utility, voronoi, coscan, random, hungarian) x 5 episodes, 3600-step horizon, here on
``--maps-per-size`` bundled maps per size class (default 2: 6 maps, 540 episodes), 2 worker
processes. Prints the total wall time, the mean episode time per size class and method, and the time
the whole bundled set (all 70 maps) would take at the measured rates.

    python benchmarks/bench_eval.py            # the protocol (about 20 min on 2 cores)
    python benchmarks/bench_eval.py --quick    # 1 map per size class, 1 episode (54 episodes)
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections import defaultdict
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from areasearch.harness.evaluate import EvalPlan, evaluate, read_episodes
from areasearch.sim.scene import SIZE_CLASSES, bundled_index

METHODS = ["greedy", "utility", "voronoi", "coscan", "random", "hungarian"]
ROBOTS = [3, 4, 5]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1 map per size class and 1 episode")
    parser.add_argument("--maps-per-size", type=int, default=None, help="maps per size class (default 2; quick 1)")
    parser.add_argument("--episodes", type=int, default=None, help="episodes per (map, team) (default 5; quick 1)")
    parser.add_argument("--max-steps", type=int, default=3600)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=None, help="results folder (default: a fresh temporary one)")
    args = parser.parse_args()
    per_size = args.maps_per_size or (1 if args.quick else 2)
    episodes = args.episodes or (1 if args.quick else 5)
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_eval_")) / "run"

    t0 = time.perf_counter()
    evaluate(
        EvalPlan(
            METHODS, ROBOTS, ["bundled"], episodes, 0, args.max_steps, out, workers=args.workers, maps_per_size=per_size
        )
    )
    wall = time.perf_counter() - t0
    rows = read_episodes(out / "episodes.csv")
    by_size: dict[str, list[float]] = defaultdict(list)
    by_method: dict[str, list[float]] = defaultdict(list)
    for r in rows:
        by_size[r["size_class"]].append(r["wall_s"])
        by_method[r["method"]].append(r["wall_s"])
    busy = sum(r["wall_s"] for r in rows)
    maps = sorted({(SIZE_CLASSES.index(r["size_class"]), r["size_class"], r["map"]) for r in rows})
    print(
        f"\nprotocol: {len(maps)} maps ({per_size} per size class), robots {ROBOTS}, {len(METHODS)} methods, "
        f"{episodes} episode(s), max_steps {args.max_steps}, {args.workers} workers -> {len(rows)} episodes"
    )
    print("maps: " + ", ".join(f"{m} ({s})" for _, s, m in maps))
    print(f"total wall time: {wall:.1f} s  ({len(rows) / wall:.2f} episodes/s, worker utilisation {busy / wall:.2f})")
    print("mean episode time by size class: " + ", ".join(f"{s} {sum(v) / len(v):.2f} s" for s, v in by_size.items()))
    print("mean episode time by method:     " + ", ".join(f"{m} {sum(v) / len(v):.2f} s" for m, v in by_method.items()))
    counts: dict[str, int] = defaultdict(int)
    for entry in bundled_index():
        counts[entry["size_class"]] += 1
    full_busy = sum(
        counts[s] * len(ROBOTS) * len(METHODS) * 5 * sum(v) / len(v) for s, v in by_size.items()
    )  # seconds of episode time for all bundled maps, 5 episodes
    full_episodes = sum(counts.values()) * len(ROBOTS) * len(METHODS) * 5
    print(
        f"extrapolated: all {sum(counts.values())} bundled maps x 5 episodes ({full_episodes} episodes) "
        f"~ {full_busy / (busy / wall) / 3600:.1f} h with {args.workers} workers; "
        f"--maps-per-size {per_size} x 5 episodes "
        f"~ {len(maps) * len(ROBOTS) * len(METHODS) * 5 * (busy / len(rows)) / (busy / wall) / 60:.0f} min"
    )
    print(f"results: {out}")


if __name__ == "__main__":
    main()
