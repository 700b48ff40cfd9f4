"""The validation score of training (mean Cover % over the horizon, ``areasearch.train.coverage_auc``)
of every method of an ``areasearch eval`` folder, with 95 % intervals and paired differences.

    python scripts/coverage_auc.py results/val-reference [--reference greedy]

With ``--maps bundled:val --robots 3 --episodes 3 --seed S`` the evaluation plays exactly the episodes
of a training run's validation with run seed S (the same ``episode_seed``), so its scores compare
with the ``eval/coverage_auc`` of that run's ``progress.csv``.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from areasearch.evaluate import read_curves
from areasearch.train import coverage_auc


def interval(x: np.ndarray) -> float:
    return float(1.96 * x.std(ddof=1) / math.sqrt(len(x))) if len(x) > 1 else float("nan")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path, help="an areasearch eval output folder")
    parser.add_argument("--reference", default=None, help="method the paired differences are taken against")
    parser.add_argument("--max-steps", type=int, default=3600, help="horizon of the score (default 3600)")
    args = parser.parse_args()
    curves = read_curves(args.folder / "curves.jsonl")
    scores: dict[str, dict[tuple[str, int, int], float]] = defaultdict(dict)
    for (method, map_id, robots, episode, _seed), rec in curves.items():
        scores[method][(map_id, robots, episode)] = coverage_auc(rec["steps"], rec["covered_pct"], args.max_steps)
    if not scores:
        print(f"coverage_auc: {args.folder}: no curves", file=sys.stderr)
        return 2
    reference = args.reference if args.reference in scores else None
    print(f"| method | episodes | coverage AUC | 95 % | minus {reference or '-'} | 95 % |")
    print("|---|---:|---:|---:|---:|---:|")
    for method in sorted(scores, key=lambda m: -np.mean(list(scores[m].values()))):
        x = np.array(list(scores[method].values()))
        line = f"| {method} | {len(x)} | {x.mean():.2f} | ± {interval(x):.2f} |"
        if reference and method != reference:
            keys = sorted(set(scores[method]) & set(scores[reference]))
            d = np.array([scores[method][k] - scores[reference][k] for k in keys])
            line += f" {d.mean():+.2f} | ± {interval(d):.2f} |"
        else:
            line += " | |"
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
