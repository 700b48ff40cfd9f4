"""Learned policies over their training seeds: the spread of their test results, the median seed, and
its paired differences against NCM and the best classical planner (the bar of the paper's claim,
docs/results.md).

    python scripts/seed_summary.py results/paper-seeds --policies dahgnn ncm dahgnn-no-type dahgnn-no-history \
        --classical greedy utility voronoi coscan hungarian random [--table 3] [--curves docs/training-curves.png]
    python scripts/seed_summary.py --curves docs/training-curves.png   # the validation curves only

The evaluation folder holds one method per training seed, named ``<policy>-s<seed>`` (``areasearch eval
--policy dahgnn-s0=runs/dahgnn-s0/policy ...``, as ``scripts/train_campaign.py`` names the runs), and
the classical planners, all on the same paired episodes. Printed, per team size and size class:

* each policy's Cover % and Time_C per seed, their mean and range over seeds, and which seed is the
  median (by mean Cover % over the episodes all its seeds have played, ties to Time_C; with
  ``--median-robots R`` over those of team size R only, e.g. 3, the team of the bar);
* the median seed of each policy against the median NCM seed and against the best classical planners
  of that cell (by mean Cover %, ties broken by Time_C; and by mean Time_C), paired by episode: mean
  difference with its 95 % interval (normal approximation), Cover % (higher is better) and Time_C
  (lower is better). "beyond" marks a difference whose interval excludes 0;
* every seed at once: per episode, the mean of a policy's seeds, against the NCM seeds' mean and the
  best classical planners (a reading that does not hang on which seed is the median);
* the bar of the paper's claim for ``--bar`` (default ``dahgnn``): its median seed covers more than
  the median NCM seed and the best classical planner by Cover %, and reaches 80 % coverage sooner
  than the median NCM seed and the best classical planner by Time_C, every difference beyond its
  interval; met or not, with the comparisons that fail.

``--rival`` (default ``ncm``) names the learned policy that plays NCM's part in the paired tables and
the bar: ``--bar dahgnn-120k --rival ncm-120k`` holds a variant to the rival trained with the same
decision budget (the learned policies are compared at equal budgets).

``--median POLICY=RUN`` (repeatable) fixes a policy's median seed instead of ranking the seeds on
this folder: a replication on fresh episodes holds the seeds chosen on the first evaluation (the
shipped ones) to the bar, ``--median dahgnn-120k=dahgnn-120k-s2 --median ncm-120k=ncm-120k-s0``.

``--table ROBOTS`` adds the front page's compact table of that team size: the classical planners
and each policy's median seed (with the range of its seeds' means), Explo %, Time_E, Cover %, Time_C.

A time (Time_E, Time_C) of a method some of whose episodes never reached 80 % within the horizon is
censored, by :mod:`areasearch.harness.report`'s rule: such an episode counts the horizon, so the mean is a lower
bound, printed ``> mean`` without interval, and such a planner is not picked as the fastest classical
planner while another one reached 80 % in every episode. A paired Time_C difference over censored
episodes is a bound, not an estimate: the tables and the bar name the censored episodes.

``--curves FILE`` draws every run's validation curve (``results/training/<run>/eval.csv``, mean
coverage AUC per validation, by decisions), one panel per policy; with ``--budgets 120k 300k`` each
panel overlays the policy's runs at those budgets (``<policy>-120k-s<seed>`` and ``<policy>-300k-s<seed>``),
one colour family per budget, so that the two budgets' curves compare on one axis of decisions:

    python scripts/seed_summary.py --curves docs/budget-curves.png --policies dahgnn ncm --budgets 120k 300k
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

from areasearch.harness.report import METRICS, metric_stat, run_report, size_rank
from areasearch.sim.scene import SIZE_CLASSES
from areasearch.training.runfolder import validation_scores

ROOT = Path(__file__).resolve().parent.parent
TIMES = {m.key: m for m in METRICS if m.reached}
"""The censored metrics (Time_E, Time_C) by episode field."""

Cell = dict[str, dict[tuple[str, str], dict[str, str]]]
"""One (team size, size class): per method, its episodes by (map, episode)."""


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


def censored(eps: list[dict[str, str]], key: str) -> int:
    """How many of ``eps`` never reached 80 % within the horizon on ``key`` (``time_e``, ``time_c``), by
    the rule of :func:`areasearch.harness.report.summarize` (their ``reached_e`` / ``reached_c`` false); 0 for
    any other key."""
    metric = TIMES.get(key)
    return metric_stat(metric, eps).censored if metric is not None and eps else 0


def time_text(mean: float, is_censored: bool) -> str:
    """A mean time with thousands separators, ``> mean`` where it is a lower bound."""
    return f"> {mean:,.0f}" if is_censored else f"{mean:,.0f}"


def span(values: list[tuple[float, bool]], fmt: str) -> str:
    """``low-high`` of (value, censored) pairs, a censored end as ``> value`` (then ``low to high``)."""
    low, high = min(values), max(values)
    if not low[1] and not high[1]:
        return f"{low[0]:{fmt}}-{high[0]:{fmt}}"
    return " to ".join(f"> {v:{fmt}}" if c else f"{v:{fmt}}" for v, c in (low, high))


def rank(cell: dict[str, dict[tuple[str, str], dict[str, str]]], method: str) -> tuple[float, float]:
    """(mean Cover %, minus mean Time_C) of a method in a cell: higher is better."""
    eps = list(cell.get(method, {}).values())
    return (float(np.mean([float(e["covered_pct"]) for e in eps])), -float(np.mean([float(e["time_c"]) for e in eps])))


def difference(cell: dict[str, dict[tuple[str, str], dict[str, str]]], a: str, b: str, key: str) -> tuple[float, float]:
    """Mean of ``a`` minus ``b`` over the episodes both played, and its 95 % half-width (nan: < 2 episodes)."""
    keys = sorted(set(cell.get(a, {})) & set(cell.get(b, {})))
    if len(keys) < 2:
        return float("nan"), float("nan")
    d = np.array([float(cell[a][k][key]) - float(cell[b][k][key]) for k in keys])
    return float(d.mean()), interval(d)


def beyond(mean: float, ci: float, key: str) -> int:
    """+1 better beyond the interval, -1 worse beyond it, 0 within it (or not measured)."""
    if not abs(mean) > ci:  # nan compares False
        return 0
    better = mean > 0 if key == "covered_pct" else mean < 0
    return 1 if better else -1


def paired(cell: dict[str, dict[tuple[str, str], dict[str, str]]], a: str, b: str, key: str) -> str:
    mean, ci = difference(cell, a, b, key)
    if math.isnan(ci):
        return "n/a"
    mark = {1: " beyond, better", -1: " beyond, worse", 0: ""}[beyond(mean, ci, key)]
    bound = censored_pair(cell, a, b, key)
    return f"{mean:+.2f} ± {ci:.2f}{mark}" + (f" (a bound: {bound})" if bound else "")


def bests(cell: Cell, classical: list[str]) -> tuple[str, str]:
    """The best classical planner of a cell by Cover % (ties: Time_C) and by Time_C (ties: Cover %); by
    Time_C one whose episodes all reached 80 % before any whose Time_C is censored (a lower bound)."""
    present = [m for m in classical if cell.get(m)]
    by_cover = max(present, key=lambda m: rank(cell, m))
    by_time = max(present, key=lambda m: (not censored(list(cell[m].values()), "time_c"), *rank(cell, m)[::-1]))
    return by_cover, by_time


def faster_bounds(cell: Cell, classical: list[str], chosen: str) -> list[str]:
    """The classical planners whose censored Time_C (a lower bound) does not exceed ``chosen``'s: any of
    them may be the fastest."""
    mean = -rank(cell, chosen)[1]
    return [
        m
        for m in classical
        if m != chosen and cell.get(m) and censored(list(cell[m].values()), "time_c") and -rank(cell, m)[1] <= mean
    ]


def censored_pair(cell: Cell, a: str, b: str, key: str) -> str:
    """Where the difference of ``a`` and ``b`` on ``key`` covers censored episodes: which, out of how many
    paired ones (the difference is then a bound, not an estimate); empty otherwise."""
    keys = sorted(set(cell.get(a, {})) & set(cell.get(b, {})))
    counts = {m: censored([cell[m][k] for k in keys], key) for m in (a, b)}
    if not any(counts.values()):
        return ""
    return ", ".join(f"{m} {n}" for m, n in counts.items() if n) + f" of {len(keys)} censored"


def verdict(cell: Cell, median: str, rivals: dict[str, list[str]]) -> tuple[bool, list[str], list[str]]:
    """The bar of the paper's claim in one cell: ``median`` covers more than every rival of
    ``rivals["covered_pct"]`` and reaches 80 % coverage sooner than every rival of ``rivals["time_c"]``,
    each beyond the 95 % interval of the paired difference. Returns (met, the comparisons that fail,
    the comparisons over censored episodes: bounds, not estimates, whichever way they went)."""
    failed, bounds = [], []
    for key, names in rivals.items():
        for other in names:
            mean, ci = difference(cell, median, other, key)
            what = "Cover %" if key == "covered_pct" else "Time_C"
            if beyond(mean, ci, key) != 1:
                failed.append(f"{what} vs {other} {mean:+.2f} ± {ci:.2f}")
            bound = censored_pair(cell, median, other, key)
            if bound:
                bounds.append(f"{what} vs {other} ({bound})")
    return not failed, failed, bounds


def seed_mean(cell: Cell, names: list[str]) -> dict:
    """Per episode, the mean Cover % and Time_C of a policy's seeds (the episodes every seed played);
    its Time_C is censored where any seed's is."""
    keys = set.intersection(*(set(cell.get(n, {})) for n in names)) if names else set()
    return {
        k: {m: str(np.mean([float(cell[n][k][m]) for n in names])) for m in ("covered_pct", "time_c")}
        | {"reached_c": str(not censored([cell[n][k] for n in names], "time_c"))}
        for k in sorted(keys)
    }


def compact_table(by: dict, robots: int, shown: list[str], seeds: dict[str, list[str]], medians: dict[str, str]) -> str:
    """The front page's table: one row per size class and method (a learned policy by its median seed,
    with the range of its seeds' means), the paper's four metrics, means over episodes; a censored time
    ``> mean``."""
    out = [
        "| scenes | method | Explo % | Time_E (step) | Cover % | Time_C (step) |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for size in SIZE_CLASSES:
        cell = by.get((robots, size), {})
        for method in shown:
            name = medians.get(method, method)
            eps = list(cell.get(name, {}).values())
            if not eps:
                continue
            mean = {
                k: float(np.mean([float(e[k]) for e in eps]))
                for k in ("explored_pct", "time_e", "covered_pct", "time_c")
            }
            cover = f"{mean['covered_pct']:.1f}"
            time_e, time = (time_text(mean[k], censored(eps, k) > 0) for k in ("time_e", "time_c"))
            label = method
            if method in seeds:
                label = f"{method} (seed {name.rsplit('-s', 1)[1]} of {len(seeds[method])})"
                runs = [list(cell.get(n, {}).values()) for n in seeds[method]]
                c = [(float(np.mean([float(e["covered_pct"]) for e in r])), False) for r in runs if r]
                t = [(float(np.mean([float(e["time_c"]) for e in r])), censored(r, "time_c") > 0) for r in runs if r]
                if len(c) > 1:
                    cover += f" ({span(c, '.1f')})"
                    time += f" ({span(t, ',.0f')})"
            out.append(f"| {size} | {label} | {mean['explored_pct']:.1f} | {time_e} | {cover} | {time} |")
    return "\n".join(out)


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
    parser.add_argument(
        "--budgets",
        nargs="+",
        metavar="BUDGET",
        help="with --curves: overlay each policy's runs <policy>-<BUDGET>-s<seed> of these budgets (e.g. 120k 300k)",
    )
    parser.add_argument(
        "--median-robots", type=int, metavar="R", help="rank the seeds on this team size's episodes only (default: all)"
    )
    parser.add_argument("--bar", default="dahgnn", help="the policy whose median seed is held to the bar")
    parser.add_argument(
        "--rival", default="ncm", help="the learned rival of the bar and of the paired tables (e.g. ncm-120k)"
    )
    parser.add_argument(
        "--median",
        action="append",
        default=[],
        metavar="POLICY=RUN",
        help="fix a policy's median seed (e.g. the shipped one) instead of ranking its seeds here; repeatable",
    )
    parser.add_argument("--table", type=int, metavar="ROBOTS", help="also print the compact table of this team size")
    parser.add_argument("--training", type=Path, default=ROOT / "results" / "training")
    args = parser.parse_args()
    if args.budgets and not args.curves:
        parser.error("--budgets draws curves: give --curves FILE")
    if args.curves:
        missing = [p for p in args.policies if not curve_runs(args.training, p, args.budgets)]
        if missing:
            names = ", ".join(f"{p}-{b}-s*" if b else f"{p}-s*" for p in missing for b in args.budgets or [""])
            print(f"seed_summary: no finished run ({names}) in {args.training}", file=sys.stderr)
            return 2
        draw_curves(args.training, args.policies, args.curves, args.budgets)
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
    ranked = [r for r in rows if args.median_robots is None or int(r["robots"]) == args.median_robots]
    fixed: dict[str, str] = {}
    for item in args.median:
        policy, _, run = item.partition("=")
        if policy not in seeds or run not in seeds[policy]:
            known = ", ".join(n for names in seeds.values() for n in names)
            message = f"--median {item}: not POLICY=RUN with RUN a seed of POLICY here ({known})"
            print(f"seed_summary: {message}", file=sys.stderr)
            return 2
        fixed[policy] = run
    medians = {p: fixed.get(p) or median_seed(ranked, s) for p, s in seeds.items()}
    team = f", {args.median_robots} robots" if args.median_robots else ""
    print(
        f"Median seeds (by mean Cover % over the episodes all seeds played{team}; fixed by --median: "
        f"{', '.join(fixed) or 'none'}): " + ", ".join(f"{p}: {m}" for p, m in medians.items())
    )
    by: dict[tuple[int, str], dict[str, dict[tuple[str, str], dict[str, str]]]] = defaultdict(lambda: defaultdict(dict))
    for r in rows:
        by[(int(r["robots"]), r["size_class"])][r["method"]][(r["map"], r["episode"])] = r
    for robots, size in sorted(by, key=lambda k: (k[0], size_rank(k[1]))):
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
                bound = censored(eps, "time_c") > 0
                covers.append(c.mean())
                times.append((float(t.mean()), bound))
                median = " (median)" if name == medians[policy] else ""
                cover = f"{c.mean():.2f} ± {interval(c):.2f}"
                time = f"> {t.mean():.0f}" if bound else f"{t.mean():.0f} ± {interval(t):.0f}"  # a bound: no interval
                print(f"| {policy} | {name}{median} | {cover} | {time} |")
            if len(covers) > 1:
                mean_time = f"{'> ' if any(b for _, b in times) else ''}{np.mean([v for v, _ in times]):.0f}"
                print(
                    f"| {policy} | over {len(covers)} seeds | {np.mean(covers):.2f} (range {min(covers):.2f}-"
                    f"{max(covers):.2f}) | {mean_time} (range {span(times, '.0f')}) |"
                )
        if classical:
            by_cover, by_time = bests(cell, classical)
            maybe = faster_bounds(cell, classical, by_time)
            unsure = f" ({', '.join(maybe)}: Time_C censored below it, may be faster)" if maybe else ""
            print(
                f"\nBest classical planner here: by Cover % (ties: Time_C) {by_cover}, by Time_C {by_time}{unsure}.\n"
            )
            print("| median seed | minus | Cover % | Time_C |")
            print("|---|---|---:|---:|")
            for policy, median in medians.items():
                others = [medians.get(args.rival)] if policy != args.rival and args.rival in medians else []
                for other in dict.fromkeys([*others, by_cover, by_time]):
                    if other is None:
                        continue
                    cover = paired(cell, median, other, "covered_pct")
                    time = paired(cell, median, other, "time_c")
                    print(f"| {median} | {other} | {cover} | {time} |")
            full = {p: n for p, n in seeds.items() if len(n) > 1 and seed_mean(cell, n)}
            if full:
                print("\nEvery seed at once: per episode, the mean of a policy's seeds (the interval is over")
                print("episodes; it does not hold the spread between seeds).\n")
                print("| seeds' mean | minus | Cover % | Time_C |")
                print("|---|---|---:|---:|")
                for policy, names in full.items():
                    cell[f"{policy} (seeds)"] = seed_mean(cell, names)
                for policy in full:
                    others = [f"{args.rival} (seeds)"] if policy != args.rival and args.rival in full else []
                    for other in dict.fromkeys(o for o in (*others, by_cover, by_time) if o):
                        cover = paired(cell, f"{policy} (seeds)", other, "covered_pct")
                        time = paired(cell, f"{policy} (seeds)", other, "time_c")
                        print(f"| {policy} ({len(full[policy])} seeds) | {other} | {cover} | {time} |")
            if args.bar in medians and not cell.get(medians[args.bar]):
                print(f"\nBar for {medians[args.bar]}: not measured (no episodes of it here).")
            elif args.bar in medians:
                median = medians[args.bar]
                rivals = [medians[args.rival]] if args.rival in medians and args.bar != args.rival else []
                met, failed, bounds = verdict(
                    cell, median, {"covered_pct": [*rivals, by_cover], "time_c": [*rivals, by_time]}
                )
                note = f" Over censored episodes, a bound, not an estimate: {'; '.join(bounds)}." if bounds else ""
                print(f"\nBar for {median}: " + ("met." if met else "not met: " + "; ".join(failed) + ".") + note)
    if args.table:
        shown = [*classical, *seeds]
        print(f"\n### Compact table, {args.table} robots\n")
        print(compact_table(by, args.table, shown, seeds, medians))
    return 0


def curve_runs(training: Path, policy: str, budgets: list[str] | None = None) -> dict[str, list[Path]]:
    """The runs of ``training`` whose curves a panel of ``policy`` draws, by budget: without ``budgets``
    ``{"": [<policy>-s<seed>, ...]}``; with them ``{budget: [<policy>-<budget>-s<seed>, ...]}`` (a budget
    without runs left out). Only finished runs, those with an ``eval.csv``."""
    out: dict[str, list[Path]] = {}
    for budget in budgets or [""]:
        name = f"{policy}-{budget}" if budget else policy
        runs = [
            run
            for run in sorted(training.glob(f"{name}-s*"))
            if re.fullmatch(rf"{re.escape(name)}-s\d+", run.name) and (run / "eval.csv").exists()
        ]
        if runs:
            out[budget] = runs
    return out


def draw_curves(training: Path, policies: list[str], out: Path, budgets: list[str] | None = None) -> None:
    """Every run's validation curve, one panel per policy; with ``budgets`` each panel overlays the
    policy's runs at each budget (``<policy>-<budget>-s<seed>``), one colour family per budget, on one
    axis of decisions: the curves of two budgets side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    families = ["Blues", "Oranges", "Greens", "Purples", "Reds"]
    fig, axes = plt.subplots(1, len(policies), figsize=(4.2 * len(policies), 3.4), sharey=True, squeeze=False)
    for ax, policy in zip(axes[0], policies, strict=True):
        for b, (budget, runs) in enumerate(curve_runs(training, policy, budgets).items()):
            cmap = plt.get_cmap(families[b % len(families)]) if budgets else None
            for i, run in enumerate(runs):
                xs, ys, _ = validation_scores(run)
                label = f"{budget} {run.name.rsplit('-', 1)[1]}" if budgets else run.name
                color = cmap(0.5 + 0.4 * i / max(len(runs) - 1, 1)) if cmap else None
                ax.plot(xs, ys, marker="o", markersize=3, label=label, color=color)
        ax.set_title(policy)
        ax.set_xlabel("decisions")
        # 300,000 decisions in plain digits run into each other; thousands read as "300k"
        ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x / 1000:.0f}k" if x else "0"))
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    axes[0][0].set_ylabel("validation coverage AUC")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    run_report(main)
