"""The robustness study: how each method's coverage holds up as the world gets less perfect.

Reads one ``areasearch eval`` folder per condition under ROOT, named by the condition:

* ``none``, ``low``, ``medium``, ``high``: the realism presets (``--realism NAME``; ``none`` is the
  perfect world of every other result);
* ``comm-<R>m`` (e.g. ``comm-10m``, ``comm-5m``, ``comm-2m``): communication limited to a disc of R
  metres (``--set comm.model=disc --set comm.range_m=R``), every other imperfection off; ``none`` is
  the full-communication end of that axis.

Each folder's ``config.json`` is checked against its name (the preset it recorded, the communication
it played), so a folder cannot be read under the wrong label. For every team size and condition it
prints, per method, Cover % and the coverage AUC (mean Cover % over the horizon,
``areasearch.training.validation.coverage_auc``) with 95 % intervals over episodes, Time_C (``> m``
when some episode never reached 80 %: a lower bound), and each method's paired change of the coverage
AUC against the perfect world on the same episodes (same map, team and episode index; the episode
seeds depend on those alone, so every condition plays the same start poses and targets).
``--lead M`` adds M's paired lead over each method and the change of that lead against the perfect world (a
difference in differences: does M degrade more than the method). ``--plot``
draws the coverage AUC against the preset and against the communication range, a line per method.

    python scripts/robustness.py results/robustness --robots 3 5 --plot docs/robustness.png
    python scripts/robustness.py results/robustness --wide --lead dahgnn   # a column per condition; the lead
"""

from __future__ import annotations

import argparse
import io
import json
import re
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from areasearch.errors import AreaSearchError
from areasearch.folderlock import write_atomic
from areasearch.harness.records import read_curves, read_episodes
from areasearch.harness.report import Stat, mean_ci, run_report
from areasearch.training.validation import coverage_auc

PRESETS = ("none", "low", "medium", "high")
"""The preset axis, from the perfect world to the harshest preset."""
COMM_FOLDER = re.compile(r"comm-(\d+(?:\.\d+)?)m")

Key = tuple[str, int, int]
"""An episode of a method: (map, robots, episode index)."""


class Condition:
    """One condition's episodes: per method, per episode key, the row of ``episodes.csv`` and the AUC."""

    def __init__(self, name: str, folder: Path, horizon: int | None) -> None:
        self.name = name
        config = json.loads((folder / "config.json").read_text(encoding="utf-8"))
        check_label(name, folder, config)
        self.horizon = int(horizon or config["max_steps"])
        self.rows: dict[str, dict[Key, dict[str, Any]]] = defaultdict(dict)
        self.auc: dict[str, dict[Key, float]] = defaultdict(dict)
        for row in read_episodes(folder / "episodes.csv"):
            self.rows[row["method"]][(row["map"], row["robots"], row["episode"])] = row
        for (method, map_id, robots, episode, _seed), rec in read_curves(folder / "curves.jsonl").items():
            self.auc[method][(map_id, robots, episode)] = coverage_auc(rec["steps"], rec["covered_pct"], self.horizon)


def check_label(name: str, folder: Path, config: dict[str, Any]) -> None:
    """AreaSearchError when the folder's recorded settings are not what its name says."""
    world = config.get("config", {}).get("world", {})
    comm = world.get("comm", {})
    realism = config.get("realism", "none")
    match = COMM_FOLDER.fullmatch(name)
    if match:
        if realism != "none" or comm.get("model") != "disc" or float(comm.get("range_m", -1)) != float(match[1]):
            raise AreaSearchError(f"{folder}: named {name} but its config.json records another communication")
        if any(world.get(group) for group in ("noise", "detection")):
            raise AreaSearchError(f"{folder}: named {name} but other imperfections are on")
    elif name in PRESETS:
        if realism != name or (name == "none" and any(world.get(g) for g in ("noise", "detection", "comm"))):
            raise AreaSearchError(f"{folder}: named {name} but its config.json records realism {realism!r}")
    else:
        raise AreaSearchError(f"{folder}: not a condition name (none, low, medium, high or comm-<R>m)")


def axes(conditions: dict[str, Condition]) -> dict[str, list[str]]:
    """The two axes of the study, each as the condition names found, in order."""
    presets = [p for p in PRESETS if p in conditions]
    ranges = sorted((n for n in conditions if COMM_FOLDER.fullmatch(n)), key=lambda n: -float(n[5:-1]))
    return {"preset": presets, "comm range": (["none"] if "none" in conditions else []) + ranges}


def time_c(rows: list[dict[str, Any]]) -> str:
    """Mean Time_C, ``> m`` when some episode never reached 80 % (counted at the horizon)."""
    times = mean_ci([r["time_c"] for r in rows])
    if not all(r["reached_c"] for r in rows):
        return f"> {times.mean:.0f}"
    return cell(times, 0)


def cell(stat: Stat, decimals: int = 2, sign: str = "") -> str:
    half = "" if stat.half_width is None else f" ± {stat.half_width:.{decimals}f}"
    return f"{stat.mean:{sign}.{decimals}f}{half}"


def episodes(cond: Condition, method: str, robots: int) -> set[Key]:
    """The episodes of ``method`` with ``robots`` robots that ``cond`` holds, with their curves."""
    return {k for k in cond.rows.get(method, {}) if k[1] == robots and k in cond.auc.get(method, {})}


def table(conditions: dict[str, Condition], names: list[str], robots: int, methods: list[str]) -> str:
    """The markdown table of one axis and team size, each method over the episodes every condition of the axis
    holds (a condition still being played shows the episodes it has, the others the same ones)."""
    head = "| Method | Condition | Cover (%) | Time_C (step) | Coverage AUC (%) | AUC minus none | pairs |"
    lines = [head, "|---|---|---:|---:|---:|---:|---:|"]
    base = conditions.get("none")
    for method in methods:
        common = set.intersection(*(episodes(conditions[name], method, robots) for name in names))
        for name in names:
            cond = conditions[name]
            keys = sorted(common)
            if not keys:
                continue
            rows = [cond.rows[method][k] for k in keys]
            auc = [cond.auc[method][k] for k in keys]
            paired = ""
            if base is not None and name != "none" and len(keys) > 1:
                paired = cell(mean_ci([cond.auc[method][k] - base.auc[method][k] for k in keys]), sign="+")
            lines.append(
                f"| {method} | {name} | {cell(mean_ci([r['covered_pct'] for r in rows]))} | {time_c(rows)} "
                f"| {cell(mean_ci(auc))} | {paired} | {len(keys)} |"
            )
    return "\n".join(lines)


def wide_table(conditions: dict[str, Condition], names: list[str], robots: int, methods: list[str]) -> str:
    """One row per method, one column per condition of the axis: Cover %, the coverage AUC and the mean Time_C
    (``>`` when some episode never reached 80 %), and under each condition but ``none`` the AUC's paired change
    against ``none`` (bold: beyond its 95 % interval)."""
    lines = ["| Method | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for method in methods:
        keys = sorted(set.intersection(*(episodes(conditions[name], method, robots) for name in names)))
        if len(keys) < 2:
            continue
        cells = []
        for name in names:
            cond = conditions[name]
            cover = mean_ci([cond.rows[method][k]["covered_pct"] for k in keys]).mean
            auc = mean_ci([cond.auc[method][k] for k in keys]).mean
            text = f"{cover:.1f} / {auc:.1f} / {time_c([cond.rows[method][k] for k in keys]).split(' ±')[0]}"
            if name != "none":
                text += f" ({paired(mean_ci([cond.auc[method][k] - conditions['none'].auc[method][k] for k in keys]))})"
            cells.append(text)
        lines.append(f"| {method} ({len(keys)}) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def value(cond: Condition, method: str, key: Key, metric: str) -> float:
    """An episode's figure: its coverage AUC (``auc``) or its Cover % at the horizon (``cover``)."""
    return cond.auc[method][key] if metric == "auc" else float(cond.rows[method][key]["covered_pct"])


def paired(stat: Stat) -> str:
    """A paired difference as a table shows it: mean ± 95 % interval, bold when beyond it."""
    text = f"{stat.mean:+.1f} ± {stat.half_width:.1f}"
    return f"**{text}**" if abs(stat.mean) > (stat.half_width or 0) else text


def lead_table(
    conditions: dict[str, Condition],
    names: list[str],
    robots: int,
    methods: list[str],
    lead: str,
    metric: str,
    change: bool = False,
) -> str:
    """Does ``lead``'s advantage survive: per other method and condition, ``lead``'s coverage AUC (or Cover %)
    minus the method's on the same episodes, ± 95 % interval (bold: beyond it). ``change``: does ``lead``
    degrade more than each method: per condition but ``none``, the paired change of that lead against the
    perfect world, ``(lead - method)[condition] - (lead - method)[none]`` (negative: ``lead`` lost more)."""
    base = conditions["none"] if change else None
    shown = [name for name in names if name != "none"] if change else names
    head = f"change of {lead}'s lead" if change else f"{lead} minus"
    lines = [f"| {head} | " + " | ".join(shown) + " |", "|---|" + "---:|" * len(shown)]
    for method in methods:
        if method == lead:
            continue
        cells = []
        for name in shown:
            played = [conditions[name]] + ([base] if base is not None else [])
            keys = sorted(set.intersection(*(episodes(c, m, robots) for c in played for m in (method, lead))))
            if len(keys) < 2:
                cells.append("")
                continue
            leads = [[value(c, lead, k, metric) - value(c, method, k, metric) for k in keys] for c in played]
            cells.append(paired(mean_ci(list(np.subtract(leads[0], leads[1])) if base is not None else leads[0])))
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(conditions: dict[str, Condition], robots: list[int], methods: list[str], path: Path) -> None:
    """Coverage AUC against each axis, a line per method (its mean over the episodes every condition of the axis
    holds; the intervals are in the tables), a row per team size; PNG, written atomically."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    axis_names = {k: v for k, v in axes(conditions).items() if v}
    fig = Figure(figsize=(5.2 * len(axis_names), 3.8 * len(robots)), dpi=110)
    FigureCanvasAgg(fig)
    grid = fig.subplots(len(robots), len(axis_names), squeeze=False)
    for row, team in enumerate(robots):
        for col, (axis, names) in enumerate(axis_names.items()):
            ax = grid[row][col]
            for method in methods:
                keys = set.intersection(*(episodes(conditions[name], method, team) for name in names))
                if keys:
                    ys = [float(np.mean([conditions[name].auc[method][k] for k in keys])) for name in names]
                    ax.plot(range(len(names)), ys, label=f"{method} ({len(keys)})", marker="o", linewidth=1.4)
            ticks = ["full" if (axis == "comm range" and n == "none") else n.replace("comm-", "") for n in names]
            ax.set_xticks(range(len(names)), ticks)
            ax.set_xlabel("realism preset" if axis == "preset" else "communication range")
            ax.set_ylabel("coverage AUC (mean Cover %)")
            ax.set_title(f"{team} robots")
            ax.grid(alpha=0.3)
    grid[0][-1].legend(loc="best", fontsize=7)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    write_atomic(path, buffer.getvalue(), "robustness figure")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", type=Path, help="folder holding one eval folder per condition")
    parser.add_argument("--robots", type=int, nargs="+", default=[3, 5], help="team sizes (default 3 5)")
    parser.add_argument("--methods", nargs="+", help="these methods, in this order (default: all, sorted)")
    parser.add_argument("--max-steps", type=int, help="horizon of the coverage AUC (default: each folder's)")
    parser.add_argument("--plot", type=Path, help="write the figure here (PNG)")
    parser.add_argument("--wide", action="store_true", help="a row per method, a column per condition")
    parser.add_argument("--lead", metavar="METHOD", help="add METHOD's paired lead over each other method")
    parser.add_argument(
        "--metric",
        choices=("auc", "cover"),
        default="auc",
        help="the figure of the --lead tables: the coverage AUC (default) or Cover %% at the horizon",
    )
    parser.add_argument("--only", nargs="+", metavar="NAME", help="these conditions only (default: every folder)")
    args = parser.parse_args()
    if not args.root.is_dir():
        raise AreaSearchError(f"{args.root}: not a folder")
    conditions = {
        d.name: Condition(d.name, d, args.max_steps)
        for d in sorted(args.root.iterdir())
        if d.is_dir() and (d / "episodes.csv").is_file() and (not args.only or d.name in args.only)
    }
    if "none" not in conditions:
        raise AreaSearchError(f"{args.root}: no 'none' folder (the perfect world every condition is paired with)")
    methods = args.methods or sorted({m for c in conditions.values() for m in c.rows})
    for axis, names in axes(conditions).items():
        if len(names) < 2:
            continue
        for team in args.robots:
            print(f"## {team} robots, by {axis}\n")
            if args.wide:
                print("Cover % / coverage AUC % / Time_C (the AUC's paired change against none ± 95 % interval)\n")
                print(wide_table(conditions, names, team, methods) + "\n")
            else:
                print(table(conditions, names, team, methods) + "\n")
            if args.lead:
                figure = "Coverage AUC" if args.metric == "auc" else "Cover %"
                print(f"{figure}, {args.lead} minus each method on the same episodes\n")
                print(lead_table(conditions, names, team, methods, args.lead, args.metric) + "\n")
                print(f"{figure}: change of {args.lead}'s lead against none (negative: {args.lead} lost more)\n")
                print(lead_table(conditions, names, team, methods, args.lead, args.metric, change=True) + "\n")
    if args.plot:
        plot(conditions, args.robots, methods, args.plot)
    return 0


if __name__ == "__main__":
    run_report(main)
