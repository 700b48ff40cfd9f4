"""Compare two evaluations of the same paired episodes, per method: what a planner change did.

    python scripts/compare_episodes.py OLD_episodes.csv NEW_episodes.csv
    python scripts/compare_episodes.py <(git show e4d34de:results/test-3robots/episodes.csv) \\
        results/test-3robots/episodes.csv

Episodes are paired by (method, map, robots, episode) and must have the same seed in both files (the
harness gives an episode the same seed whatever the code, so two runs of one command pair up). Prints
one Markdown table: per method the mean collisions per episode, the mean Cover %, the episodes with
more than 2,000 collisions (robots blocked for good) and the episodes that end with the whole map
explored but targets left, old and new, and the episodes that are identical (every recorded outcome
the same, wall time aside): a change that should not alter behaviour (a faster kernel) leaves them all so.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
from pathlib import Path

KEY = ("method", "map", "robots", "episode")
NEEDED = {*KEY, "seed", "collisions", "covered_pct", "explored_pct"}


def load(path: str) -> dict[tuple[str, ...], dict[str, str]]:
    try:
        with Path(path).open(newline="") as f:
            reader = csv.DictReader(f)
            missing = NEEDED - set(reader.fieldnames or [])
            if missing:
                sys.exit(f"error: {path} is not an episodes.csv of areasearch eval (no {', '.join(sorted(missing))})")
            return {tuple(row[k] for k in KEY): row for row in reader}
    except OSError as e:
        sys.exit(f"error: cannot read {path}: {e.strerror}")


def compare(old: dict[tuple[str, ...], dict[str, str]], new: dict[tuple[str, ...], dict[str, str]]) -> str:
    pairs = [k for k in new if k in old]
    if not pairs:
        sys.exit("error: the two files share no episode")
    for k in pairs:
        if old[k]["seed"] != new[k]["seed"]:
            sys.exit(f"error: episode {k} has seed {old[k]['seed']} in one file and {new[k]['seed']} in the other")
    methods: dict[str, list[tuple[str, ...]]] = {}
    for k in pairs:
        methods.setdefault(k[0], []).append(k)

    def mean(rows: dict, keys: list, field: str) -> float:
        return statistics.mean(float(rows[k][field]) for k in keys)

    def blocked(rows: dict, keys: list) -> int:
        return sum(int(rows[k]["collisions"]) > 2000 for k in keys)

    def left(rows: dict, keys: list) -> int:
        return sum(float(rows[k]["explored_pct"]) >= 99.95 and float(rows[k]["covered_pct"]) < 100.0 for k in keys)

    def identical(keys: list) -> int:
        same = 0
        for k in keys:
            fields = (set(old[k]) & set(new[k])) - {"wall_s"}
            same += all(old[k][f] == new[k][f] for f in fields)
        return same

    lines = [
        f"{len(pairs)} paired episodes (old -> new)",
        "",
        "| method | episodes | collisions per episode | Cover % | > 2,000 collisions | explored, targets left "
        "| identical |",
        "|---|---|---|---|---|---|---|",
    ]
    for method, keys in [*methods.items(), ("all", pairs)]:
        lines.append(
            f"| {method} | {len(keys)} | {mean(old, keys, 'collisions'):.0f} -> {mean(new, keys, 'collisions'):.0f} "
            f"| {mean(old, keys, 'covered_pct'):.2f} -> {mean(new, keys, 'covered_pct'):.2f} "
            f"| {blocked(old, keys)} -> {blocked(new, keys)} | {left(old, keys)} -> {left(new, keys)} "
            f"| {identical(keys)} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("old", help="episodes.csv of the earlier run")
    parser.add_argument("new", help="episodes.csv of the later run")
    args = parser.parse_args()
    print(compare(load(args.old), load(args.new)))


if __name__ == "__main__":
    main()
