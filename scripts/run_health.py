"""A training run's health at a glance: the ``health/*`` and key ``losses/*`` columns of its
``progress.csv``, averaged over its first, middle and last iterations, with the largest value of
every per-round column over the whole run.

    python scripts/run_health.py results/training/dahgnn-s0 [--window 10]

What to look for (docs/training.md#the-run-folder): feature RMS that stays of order 1 from round to
round and through training, a score spread bounded by twice ``network.score_scale``, a largest
attention weight well below 1 (1 is one-hot attention), no saturated MLP-attention logit.
"""

from __future__ import annotations

import argparse
import csv
import re
import sys
from pathlib import Path

import numpy as np

from areasearch.harness.report import run_report

SUMMARY = ("losses/approx_kl", "losses/clipfrac", "losses/entropy", "losses/minibatches", "losses/explained_variance")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a training run folder (or its copy in results/training/)")
    parser.add_argument("--window", type=int, default=10, help="iterations averaged at each end and the middle")
    args = parser.parse_args()
    path = args.run / "progress.csv"
    if not path.exists():
        print(f"run_health: {path}: no such file", file=sys.stderr)
        return 2
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    columns = [k for k in (rows[0] if rows else {}) if k.startswith("health/")] + [
        k for k in SUMMARY if rows and k in rows[0]
    ]
    if not rows or not any(c.startswith("health/") for c in columns):
        print(f"run_health: {path}: no health columns (a run of an earlier version?)", file=sys.stderr)
        return 2
    w = max(1, args.window)
    mid = len(rows) // 2
    parts = {"first": rows[:w], "middle": rows[max(0, mid - w // 2) : mid - w // 2 + w], "last": rows[-w:]}
    print(f"{args.run}: {len(rows)} iterations, {rows[-1]['decisions']} decisions; means over {w} iterations")
    print("| column | first | middle | last | largest |")
    print("|---|---:|---:|---:|---:|")
    for column in columns:

        def values(part: list[dict[str, str]], c: str = column) -> np.ndarray:
            return np.array([float(r[c]) for r in part if r.get(c, "") != ""])

        means = [values(p) for p in parts.values()]
        cells = [f"{m.mean():.3g}" if len(m) else "" for m in means]
        every = values(rows)
        largest = f"{every.max():.3g}" if re.search(r"round\d+_|final_", column) and len(every) else ""
        print(f"| {column.split('/', 1)[1]} | {' | '.join(cells)} | {largest} |")
    return 0


if __name__ == "__main__":
    run_report(main)
