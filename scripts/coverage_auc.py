"""The validation score of training (mean Cover % over the horizon, ``areasearch.training.train.coverage_auc``)
of every method of an ``areasearch eval`` folder, with 95 % intervals and paired differences; or of
every validation of a training run.

    python scripts/coverage_auc.py results/val-reference [--reference greedy] [--by-size]
    python scripts/coverage_auc.py results/training/dahgnn-s0 [--by-size]

With ``--maps bundled:val --robots 3 --episodes 3 --seed S`` the evaluation plays exactly the episodes
of a training run's validation with run seed S (the same ``episode_seed``), so its scores compare
with the ``eval/coverage_auc`` of that run's ``progress.csv``. A folder with an ``eval.csv`` (a
training run, or its copy in ``results/training/``) prints the score of each validation by
decisions. ``--by-size`` adds a column per size class of the maps; ``--robots R``, ``--size S`` and
``--methods M ...`` keep an eval folder's episodes of one team size, one size class, some methods:

    python scripts/coverage_auc.py results/paper-seeds --robots 3 --size large --reference ncm-s0

``--seeds S ...`` adds, for every policy with runs named ``<policy>-s<S>`` for each of those seeds, a
row ``<policy> (seeds S ...)``: per episode, the mean score of those seeds' runs. Two policies trained
with the same seeds are then compared seed for seed (the ablations of Table 6 against DA-HGNN):

    python scripts/coverage_auc.py results/paper-seeds --robots 3 --seeds 0 1 \
        --methods dahgnn-120k-s0 dahgnn-120k-s1 dahgnn-no-type-120k-s0 dahgnn-no-type-120k-s1 \
        --reference "dahgnn-120k (seeds 0 1)"
"""

from __future__ import annotations

import argparse
import csv
import math
import re
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from areasearch.harness.evaluate import read_curves
from areasearch.harness.report import run_report
from areasearch.sim.scene import SIZE_CLASSES, bundled_index
from areasearch.training.train import coverage_auc


def interval(x: np.ndarray) -> float:
    return float(1.96 * x.std(ddof=1) / math.sqrt(len(x))) if len(x) > 1 else float("nan")


def size_classes() -> dict[str, str]:
    return {entry["id"]: entry["size_class"] for entry in bundled_index()}


def by_size(scores: dict[tuple[str, int, int], float], classes: dict[str, str]) -> str:
    cells = []
    for size in SIZE_CLASSES:
        x = [v for (m, _, _), v in scores.items() if classes.get(m) == size]
        cells.append(f"{np.mean(x):.2f}" if x else "")
    return " | " + " | ".join(cells)


def seed_means(
    scores: dict[str, dict[tuple[str, int, int], float]], seeds: list[int]
) -> dict[str, dict[tuple[str, int, int], float]]:
    """Per policy with a run ``<policy>-s<S>`` for every seed S: the mean of those runs' scores on
    each episode all of them played, under the name ``<policy> (seeds S ...)``."""
    policies = {m.rsplit("-s", 1)[0] for m in scores if re.fullmatch(r".+-s\d+", m)}
    means = {}
    for policy in sorted(policies):
        runs = [f"{policy}-s{s}" for s in seeds]
        if not all(r in scores for r in runs):
            continue
        keys = set.intersection(*(set(scores[r]) for r in runs))
        name = f"{policy} (seeds {' '.join(map(str, seeds))})"
        means[name] = {k: float(np.mean([scores[r][k] for r in runs])) for k in sorted(keys)}
    return means


def training_run(folder: Path, split: bool) -> int:
    """Each validation's mean score (and per size class) from a training run's eval.csv."""
    scores: dict[int, dict[tuple[str, int, int], float]] = defaultdict(dict)
    with open(folder / "eval.csv", newline="") as f:
        for row in csv.DictReader(f):
            scores[int(row["decisions"])][(row["map"], int(row["robots"]), int(row["seed"]))] = float(
                row["coverage_auc"]
            )
    if not scores:
        print(f"coverage_auc: {folder / 'eval.csv'}: no validation rows", file=sys.stderr)
        return 2
    classes = size_classes()
    print("| decisions | episodes | coverage AUC |" + (" small | medium | large |" if split else ""))
    print("|---:|---:|---:|" + ("---:|---:|---:|" if split else ""))
    for decisions in sorted(scores):
        x = np.array(list(scores[decisions].values()))
        extra = by_size(scores[decisions], classes).removeprefix(" |") + " |" if split else ""
        print(f"| {decisions:,} | {len(x)} | {x.mean():.2f} |{extra}")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path, help="an areasearch eval output folder, or a training run folder")
    parser.add_argument("--reference", default=None, help="method the paired differences are taken against")
    parser.add_argument("--max-steps", type=int, default=3600, help="horizon of the score (default 3600)")
    parser.add_argument("--by-size", action="store_true", help="a column per size class")
    parser.add_argument("--robots", type=int, metavar="R", help="an eval folder's episodes of team size R only")
    parser.add_argument("--methods", nargs="+", help="these methods only (default: every one in the folder)")
    parser.add_argument(
        "--size", choices=SIZE_CLASSES, help="an eval folder's episodes on maps of this size class only"
    )
    parser.add_argument(
        "--seeds", nargs="+", type=int, metavar="S", help="add each policy's per-episode mean over its runs -sS"
    )
    args = parser.parse_args()
    if (args.folder / "eval.csv").exists() and not (args.folder / "curves.jsonl").exists():
        return training_run(args.folder, args.by_size)
    curves = read_curves(args.folder / "curves.jsonl")
    scores: dict[str, dict[tuple[str, int, int], float]] = defaultdict(dict)
    classes = size_classes() if args.by_size or args.size else {}
    for (method, map_id, robots, episode, _seed), rec in curves.items():
        if (args.robots and robots != args.robots) or (args.methods and method not in args.methods):
            continue
        if args.size and classes.get(map_id) != args.size:
            continue
        scores[method][(map_id, robots, episode)] = coverage_auc(rec["steps"], rec["covered_pct"], args.max_steps)
    if not scores:
        print(f"coverage_auc: {args.folder}: no curves", file=sys.stderr)
        return 2
    if args.seeds:
        scores.update(seed_means(scores, args.seeds))
    reference = args.reference if args.reference in scores else None
    head = f"| method | episodes | coverage AUC | 95 % | minus {reference or '-'} | 95 % |"
    print(head + (" small | medium | large |" if args.by_size else ""))
    print("|---|---:|---:|---:|---:|---:|" + ("---:|---:|---:|" if args.by_size else ""))
    for method in sorted(scores, key=lambda m: -np.mean(list(scores[m].values()))):
        x = np.array(list(scores[method].values()))
        line = f"| {method} | {len(x)} | {x.mean():.2f} | ± {interval(x):.2f} |"
        if reference and method != reference:
            keys = sorted(set(scores[method]) & set(scores[reference]))
            d = np.array([scores[method][k] - scores[reference][k] for k in keys])
            line += f" {d.mean():+.2f} | ± {interval(d):.2f} |"
        else:
            line += " | |"
        if args.by_size:
            line += by_size(scores[method], classes).removeprefix(" |") + " |"
        print(line)
    return 0


if __name__ == "__main__":
    run_report(main)
