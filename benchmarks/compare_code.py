"""Two versions of areasearch timed by one benchmark, alternating, as ratios new / old.

    git worktree add /tmp/old <commit>
    python benchmarks/compare_code.py --old /tmp/old/src --pairs 6 world
    python benchmarks/compare_code.py --old /tmp/old/src --pairs 6 goal_env
    python benchmarks/compare_code.py --old /tmp/old/src --pairs 5 train

Each run is a fresh process of ``benchmarks/bench_world.py --repeats 3``, ``bench_goal_env.py
--repeats 2`` or ``bench_train.py --iterations 3`` (this checkout's script) with ``PYTHONPATH`` set to
the source tree it times (``--old``, and ``--new``, by default this checkout's ``src``), so the
package imported is that tree's. One warm-up run of each compiles the numba caches; then ``--pairs``
pairs, old and new in turn, the order swapped every pair. A shared machine drifts by a third within
minutes, so the figure is the median of the pair-by-pair ratios (and their range), never two
separate runs' rates.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

BENCHMARKS = {
    "world": (
        ["benchmarks/bench_world.py", "--repeats", "3"],
        r"^(\S+)\s+\S+\s+\S+\s+([\d,]+) r-st/s\s+([\d,]+) r-st/s",
    ),
    "goal_env": (["benchmarks/bench_goal_env.py", "--repeats", "2"], r"^(\S+)\s+(?:small|medium|large)\s+([\d,]+)\s"),
    "train": (
        ["benchmarks/bench_train.py", "--iterations", "3"],
        r"^training: ([\d.]+) decisions/s, ([\d,]+) robot-steps",
    ),
}


def _number(text: str) -> float:
    return float(text.replace(",", ""))


def rates(name: str, output: str) -> dict[str, float]:
    """The figures a benchmark printed, by name."""
    found: dict[str, float] = {}
    for match in re.finditer(BENCHMARKS[name][1], output, re.M):
        groups = match.groups()
        if name == "world":
            found[f"{groups[0]} World.step"] = _number(groups[1])
            found[f"{groups[0]} ParallelEnv.step"] = _number(groups[2])
        elif name == "goal_env":
            found[groups[0]] = _number(groups[1])
        else:
            found["decisions/s"], found["robot-steps/s"] = _number(groups[0]), _number(groups[1])
    if not found:
        raise SystemExit(f"compare_code: no figures in the output of {name}:\n{output}")
    return found


def run(name: str, src: str) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": src}
    done = subprocess.run(
        [sys.executable, *BENCHMARKS[name][0]], cwd=ROOT, env=env, capture_output=True, text=True, check=False
    )
    if done.returncode:
        raise SystemExit(f"compare_code: {name} failed with {src}:\n{done.stderr[-2000:]}")
    return rates(name, done.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("benchmark", choices=tuple(BENCHMARKS))
    parser.add_argument("--old", required=True, help="the src folder of the old version")
    parser.add_argument("--new", default=str(ROOT / "src"), help="the src folder of the new version (this checkout's)")
    parser.add_argument("--pairs", type=int, default=6)
    parser.add_argument("--log", type=Path, help="append each pair's figures to this JSON-lines file")
    args = parser.parse_args()
    trees = {"old": args.old, "new": args.new}
    for src in trees.values():
        run(args.benchmark, src)  # warm-up: numba's caches of this tree
    ratios: dict[str, list[float]] = {}
    for pair in range(args.pairs):
        order = ("old", "new") if pair % 2 == 0 else ("new", "old")
        figures = {which: run(args.benchmark, trees[which]) for which in order}
        if args.log:
            with args.log.open("a") as log:
                log.write(json.dumps({"pair": pair, **figures}) + "\n")
        for key, new in figures["new"].items():
            ratios.setdefault(key, []).append(new / figures["old"][key])
        print(f"pair {pair}: " + ", ".join(f"{k} {v[-1]:.3f}" for k, v in ratios.items()), flush=True)
    for key, values in ratios.items():
        print(
            f"{args.benchmark} {key}: new/old median {statistics.median(values):.3f} over {len(values)} pairs "
            f"(min {min(values):.3f}, max {max(values):.3f})"
        )


if __name__ == "__main__":
    main()
