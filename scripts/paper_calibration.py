"""Our 3-robot results beside the DA-HGNN paper's Table 3, per size class and method.

    python scripts/paper_calibration.py results/paper-3robots/summary.json [METHOD ...]

Prints one Markdown table: for each size class and method, Explo %, Time_E, Cover % and Time_C as
"ours / paper". Ours are the means of an ``areasearch eval`` summary (its ``summary.json``, 3 robots);
the paper's are the published means of its Table 3 ("Quantitative Results of Deploying 3 Robots in
Different Scenes": iGibson, 13 / 15 / 17 small / medium / large MatterPort3D test scenes, 50
episodes each, 100 targets, 3600 steps), copied here as printed there. Methods the paper does not
report (``hungarian``, ``random``, the ablations) show "-" on its side.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

PAPER_TABLE_3: dict[str, dict[str, tuple[float, float, float, float]]] = {
    # size class -> method -> (Explo %, Time_E, Cover %, Time_C), as printed in the paper's Table 3
    "small": {
        "utility": (98.82, 646.79, 45.39, 2981.57),
        "greedy": (98.90, 452.47, 45.51, 2922.96),
        "voronoi": (98.48, 417.39, 42.82, 3047.90),
        "coscan": (98.43, 382.62, 39.51, 3167.36),
        "ncm": (98.67, 530.39, 76.40, 1768.73),
        "dahgnn": (98.96, 477.00, 77.46, 1742.53),
    },
    "medium": {
        "utility": (99.22, 1207.56, 62.28, 2525.83),
        "greedy": (99.14, 860.04, 63.84, 2281.85),
        "voronoi": (99.14, 863.51, 61.02, 2429.04),
        "coscan": (99.00, 776.64, 58.04, 2507.61),
        "ncm": (99.30, 734.30, 64.38, 2565.04),
        "dahgnn": (99.61, 650.07, 75.75, 2077.03),
    },
    "large": {
        "utility": (97.86, 1491.35, 68.20, 2475.36),
        "greedy": (98.49, 1210.48, 68.97, 2213.87),
        "voronoi": (98.64, 1199.90, 66.79, 2336.14),
        "coscan": (98.17, 1148.66, 63.52, 2455.79),
        "ncm": (98.77, 1138.69, 70.47, 2235.78),
        "dahgnn": (98.95, 1020.00, 71.38, 2160.04),
    },
}
KEYS = ("explored_pct", "time_e", "covered_pct", "time_c")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("summary", type=Path, help="summary.json of an areasearch eval run (3 robots)")
    parser.add_argument("methods", nargs="*", help="methods to show, in this order (default: all)")
    args = parser.parse_args(argv)
    summary = json.loads(args.summary.read_text())
    wanted = args.methods
    heads = ("Explo %", "Time_E", "Cover %", "Time_C")
    print("| scenes | method | " + " | ".join(f"{h} ours / paper" for h in heads) + " |")
    print("|---|---|---:|---:|---:|---:|")
    for table in summary["tables"]:
        if table["robots"] != 3:
            continue
        size = table["size_class"]
        rows = {row["method"]: row for row in table["rows"]}
        for method in wanted or list(rows):
            if method not in rows:
                continue
            paper = PAPER_TABLE_3.get(size, {}).get(method)
            cells = []
            for j, key in enumerate(KEYS):
                ours = rows[method][key]["mean"]
                digits = 1 if key.endswith("pct") else 0
                theirs = "-" if paper is None else f"{paper[j]:,.{digits}f}"
                cells.append(f"{ours:,.{digits}f} / {theirs}")
            print(f"| {size} | {method} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
