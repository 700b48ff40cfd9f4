"""Print the paper's tables for a subset of methods from an evaluation's ``summary.json``, or from
every episode of an evaluation folder.

    python scripts/paper_tables.py results/test-3robots/summary.json dahgnn dahgnn-no-type dahgnn-no-history
    python scripts/paper_tables.py results/paper-seeds greedy dahgnn-s0 ncm-s0 --robots 3

An evaluation's ``summary.json`` covers the episodes of the command that wrote it; a folder that
several commands have filled (other methods, other team sizes: the per-seed evaluation of
docs/results.md) is summarised here from all of its ``episodes.csv``, with the same statistics
(:func:`areasearch.harness.report.summarize`).

One Markdown table per (team size, size class) with the given methods in the given order (all of
them when none is given): mean +- half-width of the 95 % confidence interval, the best of the shown
rows (at the printed precision) in bold, as in the paper's Tables 3-7. The numbers are those of ``areasearch eval``'s
``summary.md``; only the selection of rows and the bold marks differ. A censored time (some episodes
never reached 80 % within the horizon: the summary's ``censored`` count) is printed ``> mean``, a lower
bound without interval (a note above the tables says so), and marked best by the rule of
:func:`areasearch.harness.report.summarize`: never itself, nor a known time that such a bound among the shown
rows does not exceed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from areasearch.errors import AreaSearchError
from areasearch.harness.report import CENSORED_NOTE, best_value, run_report

NAMES = {"explored_pct": "Explo(%)", "time_e": "Time_E (step)", "covered_pct": "Cover(%)", "time_c": "Time_C (step)"}


def _cell(stat: dict) -> str:
    """mean +- CI half-width; the mean alone where one episode gives no interval; ``> mean`` where it
    is censored (a lower bound)."""
    if stat.get("censored"):
        return f"> {stat['mean']:.2f}"
    if stat["ci95"] is None:
        return f"{stat['mean']:.2f}"
    return f"{stat['mean']:.2f} ± {stat['ci95']:.2f}"


def best_mean(rows: list[dict], metric: str) -> float | None:
    """The best mean of ``metric`` over ``rows`` at the printed precision, None where there is none: the
    largest percentage or smallest time among the uncensored rows, and no best time where a censored
    one (a lower bound) does not exceed it, since that method may be faster."""
    return best_value(
        [(round(r[metric]["mean"], 2), bool(r[metric].get("censored"))) for r in rows], metric.endswith("_pct")
    )


def tables(summary: dict, methods: list[str], robots: list[int] | None = None) -> str:
    known = {row["method"] for table in summary["tables"] for row in table["rows"]}
    missing = [m for m in methods if m not in known]
    if missing:
        raise ValueError(f"not in this summary: {' '.join(missing)} (it has {' '.join(sorted(known))})")
    out, censored_shown = [], False
    for table in summary["tables"]:
        if robots and table["robots"] not in robots:
            continue
        order = {m: i for i, m in enumerate(methods)}
        rows = sorted(
            (r for r in table["rows"] if not methods or r["method"] in order), key=lambda r: order.get(r["method"], 0)
        )
        if not rows:
            continue
        best = {m: best_mean(rows, m) for m in NAMES}
        out.append(f"{table['robots']} robots, {table['size_class']} scenes ({len(table['maps'])} maps)\n")
        out.append("| Method | " + " | ".join(NAMES.values()) + " | episodes |")
        out.append("|---|" + "---:|" * (len(NAMES) + 1))
        for r in rows:
            censored_shown |= any(r[m].get("censored") for m in NAMES)
            cells = [_cell(r[m]) for m in NAMES]
            cells = [
                f"**{c}**" if not r[m].get("censored") and round(r[m]["mean"], 2) == best[m] else c
                for c, m in zip(cells, NAMES, strict=True)
            ]
            out.append(f"| {r['method']} | " + " | ".join(cells) + f" | {r['episodes']} |")
        out.append("")
    if censored_shown:
        out = [CENSORED_NOTE, "", *out]
    return "\n".join(out)


def load(path: Path) -> dict:
    """A summary.json as written by ``areasearch eval``, or the summary of every episode of an eval folder."""
    if not path.is_dir():
        return json.loads(path.read_text())
    from areasearch.harness.evaluate import read_episodes, unique_rows
    from areasearch.harness.report import summarize

    if not (path / "episodes.csv").exists():
        raise ValueError("no episodes.csv in this folder")
    return summarize(unique_rows(read_episodes(path / "episodes.csv"))).to_dict()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("summary", type=Path, help="summary.json of an areasearch eval run, or its folder")
    parser.add_argument("methods", nargs="*", help="methods to show, in this order (default: all)")
    parser.add_argument("--robots", type=int, nargs="+", metavar="R", help="these team sizes only (default: all)")
    args = parser.parse_args(argv)
    try:
        print(tables(load(args.summary), args.methods, args.robots))
    except (OSError, ValueError, KeyError, TypeError, AreaSearchError) as exc:
        print(f"paper_tables: {args.summary}: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    run_report(main)
