"""Learned policies over their training seeds: the spread of their test results, the median seed, and
its paired differences against NCM and the best classical planner (issue 20's bar).

    python scripts/seed_summary.py results/paper-seeds --policies dahgnn ncm dahgnn-no-type dahgnn-no-history \
        --classical greedy utility voronoi coscan hungarian random [--curves docs/training-curves.png]
    python scripts/seed_summary.py --curves docs/training-curves.png   # the validation curves only

The evaluation folder holds one method per training seed, named ``<policy>-s<seed>`` (``areasearch eval
--policy dahgnn-s0=runs/dahgnn-s0/policy ...``, as ``scripts/train_campaign.py`` names the runs), and
the classical planners, all on the same paired episodes. Printed, per team size and size class:

* each policy's Cover % and Time_C per seed, their mean and range over seeds, and which seed is the
  median (by mean Cover % over the episodes all its seeds have played, ties to Time_C);
* the median seed of each policy against the median NCM seed and against the best classical planner
  of that cell (by mean Cover %, ties broken by Time_C), paired by episode: mean difference with
  its 95 % interval, Cover % (higher is better) and Time_C (lower is better). "beyond" marks a difference whose interval
  excludes 0.

``--curves FILE`` draws every run's validation curve (``results/training/<run>/eval.csv``, mean
coverage AUC per validation, by decisions), one panel per policy.
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

ROOT = Path(__file__).resolve().parent.parent
SIZES = ("small", "medium", "large")


def interval(x: np.ndarray) -> float:
    return float(1.96 * x.std(ddof=1) / math.sqrt(len(x))) if len(x) > 1 else float("nan")


def read_rows(folder: Path) -> list[dict[str, str]]:
    with open(folder / "episodes.csv", newline="") as f:
        return list(csv.DictReader(f))


def seeds_of(methods: set[str], policy: str) -> list[str]:
    pattern = re.compile(rf"^{re.escape(policy)}-s(\d+)$")
    return sorted((m for m in methods if pattern.match(m)), key=lambda m: int(m.rsplit("-s", 1)[1]))


def median_seed(rows: list[dict[str, str]], seeds: list[str]) -> str:
    """The seed whose mean Cover % (ties: minus mean Time_C) is the median, lower middle for an even
    count, over the episodes every seed has played (same map, team size and episode), so that a seed
    whose evaluation is further along is not scored on other episodes."""

    def key(r: dict[str, str]) -> tuple[str, str, str]:
        return (r["map"], r["robots"], r["episode"])

    common = set.intersection(*({key(r) for r in rows if r["method"] == m} for m in seeds))
    score = {}
    for m in seeds:
        mine = [r for r in rows if r["method"] == m and key(r) in common]
        cover = np.mean([float(r["covered_pct"]) for r in mine]) if mine else float("nan")
        time = np.mean([float(r["time_c"]) for r in mine]) if mine else float("nan")
        score[m] = (cover, -time)
    ranked = sorted(seeds, key=lambda m: score[m])
    return ranked[(len(ranked) - 1) // 2]


def rank(cell: dict[str, dict[tuple[str, str], dict[str, str]]], method: str) -> tuple[float, float]:
    """(mean Cover %, minus mean Time_C) of a method in a cell: higher is better."""
    eps = list(cell.get(method, {}).values())
    return (float(np.mean([float(e["covered_pct"]) for e in eps])), -float(np.mean([float(e["time_c"]) for e in eps])))


def paired(cell: dict[str, dict[tuple[str, str], dict[str, str]]], a: str, b: str, key: str) -> str:
    keys = sorted(set(cell.get(a, {})) & set(cell.get(b, {})))
    if len(keys) < 2:
        return "n/a"
    d = np.array([float(cell[a][k][key]) - float(cell[b][k][key]) for k in keys])
    ci = interval(d)
    better = d.mean() > 0 if key == "covered_pct" else d.mean() < 0
    mark = (" beyond, better" if better else " beyond, worse") if abs(d.mean()) > ci else ""
    return f"{d.mean():+.2f} ± {ci:.2f}{mark}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "folder", type=Path, nargs="?", help="an eval folder with <policy>-s<seed> methods (none: --curves only)"
    )
    parser.add_argument("--policies", nargs="+", default=["dahgnn", "ncm", "dahgnn-no-type", "dahgnn-no-history"])
    parser.add_argument(
        "--classical", nargs="+", default=["greedy", "utility", "voronoi", "coscan", "hungarian", "random"]
    )
    parser.add_argument("--curves", type=Path, help="draw the runs' validation curves into this PNG")
    parser.add_argument("--training", type=Path, default=ROOT / "results" / "training")
    args = parser.parse_args()
    if args.curves:
        draw_curves(args.training, args.policies, args.curves)
    if args.folder is None:
        if not args.curves:
            parser.error("give an evaluation folder, --curves FILE, or both")
        return 0
    rows = read_rows(args.folder)
    methods = {r["method"] for r in rows}
    seeds = {p: seeds_of(methods, p) for p in args.policies}
    seeds = {p: s for p, s in seeds.items() if s}
    classical = [c for c in args.classical if c in methods]
    if not seeds:
        print(f"seed_summary: no <policy>-s<seed> method in {args.folder}", file=sys.stderr)
        return 2
    medians = {p: median_seed(rows, s) for p, s in seeds.items()}
    print(
        "Median seeds (by mean Cover % over the episodes all seeds played): "
        + ", ".join(f"{p}: {m}" for p, m in medians.items())
    )
    by: dict[tuple[int, str], dict[str, dict[tuple[str, str], dict[str, str]]]] = defaultdict(lambda: defaultdict(dict))
    for r in rows:
        by[(int(r["robots"]), r["size_class"])][r["method"]][(r["map"], r["episode"])] = r
    for robots, size in sorted(by, key=lambda k: (k[0], SIZES.index(k[1]) if k[1] in SIZES else 9)):
        cell = by[(robots, size)]
        print(f"\n### {robots} robots, {size} maps\n")
        print("| policy | seed | Cover % | Time_C |")
        print("|---|---|---:|---:|")
        for policy, names in seeds.items():
            covers, times = [], []
            for name in names:
                eps = list(cell.get(name, {}).values())
                if not eps:
                    continue
                c = np.array([float(e["covered_pct"]) for e in eps])
                t = np.array([float(e["time_c"]) for e in eps])
                covers.append(c.mean())
                times.append(t.mean())
                median = " (median)" if name == medians[policy] else ""
                cover, time = f"{c.mean():.2f} ± {interval(c):.2f}", f"{t.mean():.0f} ± {interval(t):.0f}"
                print(f"| {policy} | {name}{median} | {cover} | {time} |")
            if len(covers) > 1:
                print(
                    f"| {policy} | over {len(covers)} seeds | {np.mean(covers):.2f} (range {min(covers):.2f}-"
                    f"{max(covers):.2f}) | {np.mean(times):.0f} (range {min(times):.0f}-{max(times):.0f}) |"
                )
        if classical:
            best = max(classical, key=lambda m, cell=cell: rank(cell, m))
            print(f"\nBest classical planner here (Cover %, then Time_C): {best}.\n")
            print("| median seed | minus | Cover % | Time_C |")
            print("|---|---|---:|---:|")
            for policy, median in medians.items():
                others = [medians.get("ncm")] if policy != "ncm" and "ncm" in medians else []
                for other in [*others, best]:
                    if other is None:
                        continue
                    cover = paired(cell, median, other, "covered_pct")
                    time = paired(cell, median, other, "time_c")
                    print(f"| {median} | {other} | {cover} | {time} |")
    return 0


def draw_curves(training: Path, policies: list[str], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(policies), figsize=(4.2 * len(policies), 3.4), sharey=True, squeeze=False)
    for ax, policy in zip(axes[0], policies, strict=True):
        for run in sorted(training.glob(f"{policy}-s*")):
            if not re.fullmatch(rf"{re.escape(policy)}-s\d+", run.name) or not (run / "eval.csv").exists():
                continue
            scores: dict[int, list[float]] = defaultdict(list)
            with open(run / "eval.csv", newline="") as f:
                for r in csv.DictReader(f):
                    scores[int(r["decisions"])].append(float(r["coverage_auc"]))
            xs = sorted(scores)
            ax.plot(xs, [np.mean(scores[x]) for x in xs], marker="o", markersize=3, label=run.name)
        ax.set_title(policy)
        ax.set_xlabel("decisions")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    axes[0][0].set_ylabel("validation coverage AUC")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
