"""Find the stuck episodes of an evaluation, and draw the moment each one stopped making progress.

    python scripts/find_stuck.py --out DIR [--methods greedy utility voronoi coscan hungarian random]
        [--robots 3 4 5] [--maps bundled] [--episodes 3] [--seed 0] [--max-steps 3600] [--workers 2]
        [--protocol paper|passby] [--min-explored 95] [--max-collisions 1000]
    python scripts/find_stuck.py --from DIR [--maps SPEC...] [--min-explored 95] [--max-collisions 1000]

With ``--out`` it first runs (or resumes) ``areasearch eval`` into DIR through the library call
:func:`areasearch.harness.evaluate.evaluate` (default methods: every classical planner); with ``--from`` it
only scans an existing results folder (``--maps`` then says where maps that are not bundled live,
e.g. the folder the run was given). Either way it scans every episode in ``DIR/episodes.csv``.

An episode is **stuck** when the team explored less than ``--min-explored`` % (95) of a small or
medium map, when its robots collided more than ``--max-collisions`` times (1,000, team sum) on a
map of any size, or when it ran to the horizon and the team made no progress (see below) during
its last ``--max-stall`` steps (1,000; ``stalled`` in the reason column): an episode of a team with
work left that stands still. Large maps are not expected to be explored within the horizon, so a
low Explo % on one is not a symptom.

**Stalled from step**: from ``DIR/curves.jsonl`` (explored % and covered % after each decision, with
its step index), the step of the earliest decision after which neither explored % nor covered %
rose by more than ``EPSILON_PCT`` (0.05 points) up to the end of the episode: from that step on the
team made no progress. An episode whose last decision still made progress (e.g. many collisions,
yet still exploring) never stalled: its row gives the step of the last increase, its last decision,
with ``stalled`` no.

For each stuck episode the script replays it (an episode is reproducible from its map, team size,
seed, method, horizon and the run's world settings, exactly as the harness plays it:
:func:`~areasearch.harness.evaluate.make_env`, :func:`~areasearch.harness.evaluate.planner_rng`) up to that step
and draws the world at that moment, with the robots' goals and the frontier nodes, into
``DIR/stuck/<method>-<map>-r<robots>-e<episode>.png``; the replay is checked against the recorded
curve at that step (a mismatch, e.g. after a code change since the run, is reported). Replays run
one after another in this process.

Outputs (each written atomically): ``DIR/stuck.md``, a Markdown table with one row per stuck
episode linking its picture, the count of stuck episodes per method and team size, and the totals
("N stuck of M episodes"), also printed; ``DIR/stuck.csv``, the same rows. Exit status 0, stuck
episodes or not (it is a report); 2 with one ``find_stuck: error: ...`` line on bad input.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

from areasearch.config import search_config
from areasearch.envs.goal import AreaSearchEnv
from areasearch.errors import AreaSearchError
from areasearch.harness.evaluate import (
    CONFIG_FILE,
    CURVES_FILE,
    EPISODES_FILE,
    EvalPlan,
    episode_metrics,
    evaluate,
    make_env,
    planner_rng,
    read_curves,
    read_episodes,
    resolve_maps,
)
from areasearch.harness.report import size_rank, write_text
from areasearch.planners import PLANNERS, make_planner
from areasearch.sim.render import draw_world, save_png
from areasearch.sim.scene import bundled_index

PROG = "find_stuck"
CLASSICAL = ("greedy", "utility", "voronoi", "coscan", "hungarian", "random")
"""The default methods: every classical planner."""
PROTOCOLS = ("paper", "passby")
EXPLORED_SIZES = ("small", "medium")
"""Size classes on which a low Explo % makes an episode stuck."""
MIN_EXPLORED_PCT = 95.0
MAX_COLLISIONS = 1000
MAX_STALL_STEPS = 1000
"""An episode that ran to the horizon without progress during this many last steps is stuck."""
EPSILON_PCT = 0.05
"""An increase of explored % or covered % by at most this many points is no progress."""

STUCK_FIELDS = (
    "method",
    "map",
    "size_class",
    "robots",
    "episode",
    "seed",
    "explored_pct",
    "covered_pct",
    "collisions",
    "reason",
    "stalled_from_step",
    "stalled",
    "last_step",
    "picture",
    "replay_matches",
)
"""Columns of ``stuck.csv``."""

EVAL_DEFAULTS: dict[str, Any] = {
    "methods": list(CLASSICAL),
    "robots": [3, 4, 5],
    "episodes": 3,
    "seed": 0,
    "max_steps": 3600,
    "workers": 2,
    "protocol": None,
}
"""The evaluation options of ``--out`` and their defaults (``--from`` takes none of them)."""


class InputError(Exception):
    """Bad input: reported as one ``find_stuck: error: ...`` line, exit status 2."""


# ---------------------------------------------------------------------------------- analysis


@dataclass(frozen=True)
class Stall:
    """Where an episode's progress ended."""

    step: int
    """The step of the decision from which explored % and covered % rose no more (by > epsilon)."""
    stalled: bool
    """False when the last decision still made progress (``step`` is then the last decision's step)."""
    index: int
    """The decision's index in the curve (0: the reset)."""


def stall_step(
    steps: Sequence[int], explored: Sequence[float], covered: Sequence[float], eps: float = EPSILON_PCT
) -> Stall:
    """The earliest decision after which neither ``explored`` nor ``covered`` (%, one value per
    decision, index 0 the reset) rose by more than ``eps`` points up to the end. Both are monotone in
    an episode; a dip is read as the running maximum."""
    if not steps or len(steps) != len(explored) or len(steps) != len(covered):
        raise ValueError(f"a curve needs one step, explored and covered value per decision, got {len(steps)} steps")
    best_e = best_c = float("-inf")
    running: list[tuple[float, float]] = []
    for e, c in zip(explored, covered, strict=True):
        best_e, best_c = max(best_e, e), max(best_c, c)
        running.append((best_e, best_c))
    final_e, final_c = running[-1]
    k = len(steps) - 1
    while k > 0 and final_e - running[k - 1][0] <= eps and final_c - running[k - 1][1] <= eps:
        k -= 1
    return Stall(step=int(steps[k]), stalled=k < len(steps) - 1, index=k)


def stuck_reasons(
    row: dict[str, Any],
    min_explored: float = MIN_EXPLORED_PCT,
    max_collisions: int = MAX_COLLISIONS,
    curve: dict[str, Any] | None = None,
    max_steps: int | None = None,
    max_stall: int = MAX_STALL_STEPS,
) -> list[str]:
    """Why an ``episodes.csv`` row is stuck (empty: it is not): ``explored`` (less than
    ``min_explored`` % of a small or medium map), ``collisions`` (more than ``max_collisions``),
    ``stalled`` (given its ``curve`` and the run's ``max_steps``: it ran to the horizon and made no
    progress during the last ``max_stall`` steps or more)."""
    reasons = []
    if row["size_class"] in EXPLORED_SIZES and float(row["explored_pct"]) < min_explored:
        reasons.append("explored")
    if int(row["collisions"]) > max_collisions:
        reasons.append("collisions")
    if curve is not None and max_steps is not None and curve["steps"] and int(curve["steps"][-1]) >= max_steps:
        stall = stall_step(curve["steps"], curve["explored_pct"], curve["covered_pct"])
        if stall.stalled and max_steps - stall.step >= max_stall:
            reasons.append("stalled")
    return reasons


def picture_name(row: dict[str, Any]) -> str:
    return f"{row['method']}-{row['map']}-r{row['robots']}-e{row['episode']}.png"


# ---------------------------------------------------------------------------------- replay


@dataclass
class Replay:
    """An episode replayed up to a step: its environment at that moment and the last info."""

    env: AreaSearchEnv
    info: dict[str, Any]
    curve: tuple[list[int], list[float], list[float]]
    """Steps, explored %, covered % after each decision played."""


def replay(
    map_spec: str,
    robots: int,
    seed: int,
    method: str,
    max_steps: int,
    settings: dict[str, Any] | None = None,
    until: int | None = None,
) -> Replay:
    """Play an episode as the harness does (:func:`areasearch.harness.evaluate.run_episode`), stopping after
    the first decision that reaches step ``until`` (None: play it to the end)."""
    env = make_env(map_spec, robots, seed, max_steps, search_config(settings) if settings else None)
    planner = make_planner(method)
    obs, info = env.reset(seed=seed)
    planner.reset(planner_rng(seed))
    steps, explored, covered = [int(info["steps"])], [float(info["explored_pct"])], [float(info["covered_pct"])]
    done = False
    while not done and (until is None or info["steps"] < until):
        obs, _, terminated, truncated, info = env.step(planner.assign(obs))
        steps.append(int(info["steps"]))
        explored.append(float(info["explored_pct"]))
        covered.append(float(info["covered_pct"]))
        done = terminated or truncated
    return Replay(env, info, (steps, explored, covered))


def replay_metrics(rep: Replay) -> dict[str, Any]:
    """The ``episodes.csv`` metrics of a replay played to the end (and its decision count)."""
    return {**episode_metrics(rep.info), "decisions": len(rep.curve[0]) - 1}


# ---------------------------------------------------------------------------------- the folder


@dataclass(frozen=True)
class Run:
    """What the scan needs of a results folder."""

    folder: Path
    rows: list[dict[str, Any]]
    curves: dict[tuple[str, str, int, int, int], dict[str, Any]]
    max_steps: int
    settings: dict[str, Any]


def load_run(folder: Path) -> Run:
    episodes = folder / EPISODES_FILE
    if not folder.is_dir():
        raise InputError(f"{folder}: no such folder")
    if not episodes.is_file():
        raise InputError(f"{folder}: no {EPISODES_FILE}; give the --out folder of an areasearch eval run")
    config_path = folder / CONFIG_FILE
    if not config_path.is_file():
        raise InputError(f"{folder}: no {CONFIG_FILE} (the horizon and settings of the run); not an eval folder")
    try:
        config = json.loads(config_path.read_text(encoding="utf-8"))
        max_steps = int(config["max_steps"])
        settings = dict(config.get("settings") or {})
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{config_path}: not the config.json of an eval run ({exc})") from None
    try:
        rows = read_episodes(episodes)
        curves = read_curves(folder / CURVES_FILE)
    except AreaSearchError as exc:
        raise InputError(str(exc)) from None
    return Run(folder, rows, curves, max_steps, settings)


def _key(row: dict[str, Any]) -> tuple[str, str, int, int, int]:
    return (str(row["method"]), str(row["map"]), int(row["robots"]), int(row["episode"]), int(row["seed"]))


def map_specs(ids: set[str], maps: Sequence[str] | None) -> dict[str, str]:
    """What ``make_env`` is given for each map id: the id itself for a bundled map, else the spec
    among ``maps`` (resolved as ``areasearch eval --maps`` does) whose map has that id."""
    bundled = {e["id"] for e in bundled_index()}
    specs = {i: i for i in ids if i in bundled}
    missing = ids - set(specs)
    others = [m for m in maps or () if m != "bundled" and not m.startswith("bundled:") and m not in bundled]
    if missing and others:
        try:
            entries = resolve_maps(others)
        except AreaSearchError as exc:
            raise InputError(str(exc)) from None
        specs.update({e.id: e.spec for e in entries if e.id in missing})
        missing -= set(specs)
    if missing:
        raise InputError(
            f"map(s) {', '.join(sorted(missing))} of the run are not bundled; "
            "pass --maps with the maps the run was given"
        )
    return specs


def find_stuck(
    run: Run,
    maps: Sequence[str] | None = None,
    min_explored: float = MIN_EXPLORED_PCT,
    max_collisions: int = MAX_COLLISIONS,
    progress: Any = sys.stderr,
    max_stall: int = MAX_STALL_STEPS,
) -> list[dict[str, Any]]:
    """The ``stuck.csv`` rows of ``run``'s stuck episodes (in ``episodes.csv`` order), each with its
    picture drawn into ``run.folder / "stuck"``."""
    found = [
        (row, reasons)
        for row in run.rows
        if (
            reasons := stuck_reasons(
                row, min_explored, max_collisions, run.curves.get(_key(row)), run.max_steps, max_stall
            )
        )
    ]
    for row, _ in found:
        if row["method"] not in PLANNERS:
            raise InputError(f"method {row['method']!r} of {EPISODES_FILE} is not a planner of this installation")
        if _key(row) not in run.curves:
            raise InputError(
                f"{CURVES_FILE}: no curve for {row['method']} on {row['map']}, robots {row['robots']}, "
                f"episode {row['episode']}"
            )
    specs = map_specs({str(row["map"]) for row, _ in found}, maps)
    pictures = run.folder / "stuck"
    if found:
        pictures.mkdir(exist_ok=True)
    out = []
    for n, (row, reasons) in enumerate(found, start=1):
        curve = run.curves[_key(row)]
        stall = stall_step(curve["steps"], curve["explored_pct"], curve["covered_pct"])
        if progress is not None:
            print(f"{PROG}: replaying {n}/{len(found)}: {picture_name(row)[:-4]} to step {stall.step}", file=progress)
        try:
            rep = replay(
                specs[row["map"]], row["robots"], row["seed"], row["method"], run.max_steps, run.settings, stall.step
            )
        except AreaSearchError as exc:
            raise InputError(f"replaying {picture_name(row)[:-4]}: {exc}") from None
        steps, explored, covered = rep.curve
        matches = (
            steps[-1] == stall.step
            and round(explored[-1], 4) == curve["explored_pct"][stall.index]
            and round(covered[-1], 4) == curve["covered_pct"][stall.index]
        )
        if not matches and progress is not None:
            print(
                f"{PROG}: warning: the replay of {picture_name(row)[:-4]} differs from its recorded curve at step "
                f"{stall.step} (code or settings changed since the run?); its picture may not show that moment",
                file=progress,
            )
        env = rep.env
        save_png(draw_world(env.world, goals=env.goals, candidates=env.candidates), pictures / picture_name(row))
        out.append(
            {
                **{f: row[f] for f in ("method", "map", "size_class", "robots", "episode", "seed")},
                "explored_pct": row["explored_pct"],
                "covered_pct": row["covered_pct"],
                "collisions": row["collisions"],
                "reason": "+".join(reasons),
                "stalled_from_step": stall.step,
                "stalled": stall.stalled,
                "last_step": int(curve["steps"][-1]),
                "picture": f"stuck/{picture_name(row)}",
                "replay_matches": matches,
            }
        )
    return out


# ---------------------------------------------------------------------------------- reports


def to_csv(stuck: Sequence[dict[str, Any]]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(STUCK_FIELDS)
    for row in stuck:
        writer.writerow([row[f] for f in STUCK_FIELDS])
    return buf.getvalue()


def to_markdown(
    stuck: Sequence[dict[str, Any]],
    rows: Sequence[dict[str, Any]],
    min_explored: float = MIN_EXPLORED_PCT,
    max_collisions: int = MAX_COLLISIONS,
    max_stall: int = MAX_STALL_STEPS,
) -> str:
    """``stuck.md``: the stuck episodes, the count per method and team size, the totals."""
    lines = [
        "# Stuck episodes",
        "",
        f"Stuck: Explo % < {min_explored:g} on a small or medium map, more than {max_collisions:,} collisions "
        f"(team sum), or (*stalled*) run to the horizon without progress during the last {max_stall:,} steps or "
        f"more. Stalled from step: the step after which neither Explo % nor Cover % rose by more than "
        f"{EPSILON_PCT:g} points to the end; *no* in Stalled: the last decision still made progress (the step of "
        "the last increase is given).",
        "",
    ]
    if stuck:
        lines += [
            "| map | size | method | robots | episode | seed | Explo % | Cover % | collisions | reason "
            "| stalled from step | stalled | picture |",
            "|---|---|---|---:|---:|---:|---:|---:|---:|---|---:|---|---|",
        ]
        for s in stuck:
            lines.append(
                f"| {s['map']} | {s['size_class']} | {s['method']} | {s['robots']} | {s['episode']} | {s['seed']} "
                f"| {s['explored_pct']:.2f} | {s['covered_pct']:.2f} | {s['collisions']:,} | {s['reason']} "
                f"| {s['stalled_from_step']} of {s['last_step']} | {'yes' if s['stalled'] else 'no'} "
                f"| [png]({s['picture']}) |"
            )
        differ = [s for s in stuck if not s["replay_matches"]]
        if differ:
            lines += [
                "",
                f"Warning: the replay of {len(differ)} episode(s) differs from the recorded curve (code or settings "
                f"changed since the run?): {', '.join(Path(s['picture']).stem for s in differ)}.",
            ]
    else:
        lines.append("No stuck episode.")
    methods = list(dict.fromkeys(str(r["method"]) for r in rows))
    teams = sorted({int(r["robots"]) for r in rows})
    if methods:
        total: dict[tuple[str, int], int] = {}
        bad: dict[tuple[str, int], int] = {}
        for r in rows:
            total[r["method"], r["robots"]] = total.get((r["method"], r["robots"]), 0) + 1
        for s in stuck:
            bad[s["method"], s["robots"]] = bad.get((s["method"], s["robots"]), 0) + 1
        lines += [
            "",
            "Stuck / episodes per method and team size:",
            "",
            "| method | " + " | ".join(f"{r} robots" for r in teams) + " | all |",
            "|---|" + "---:|" * (len(teams) + 1),
        ]
        for m in methods:
            cells = [f"{bad.get((m, r), 0)} / {total[m, r]}" if (m, r) in total else "-" for r in teams]
            all_bad = sum(bad.get((m, r), 0) for r in teams)
            all_total = sum(total.get((m, r), 0) for r in teams)
            lines.append(f"| {m} | " + " | ".join(cells) + f" | {all_bad} / {all_total} |")
    lines += ["", f"{len(stuck)} stuck of {len(rows)} episodes", ""]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------- command line


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise InputError(message)


def parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--out", type=Path, metavar="DIR", help="run (or resume) the evaluation into DIR, then scan it")
    where.add_argument("--from", dest="source", type=Path, metavar="DIR", help="only scan this eval results folder")
    p.add_argument("--methods", nargs="+", help=f"planners to evaluate (default: {' '.join(CLASSICAL)})")
    p.add_argument("--robots", nargs="+", type=int, help="team sizes (default: 3 4 5)")
    p.add_argument(
        "--maps",
        nargs="+",
        help="maps as areasearch eval takes them (default: bundled); with --from: where maps that are not bundled are",
    )
    p.add_argument("--episodes", type=int, help="episodes per map and team size (default: 3)")
    p.add_argument("--seed", type=int, help="run seed (default: 0)")
    p.add_argument("--max-steps", type=int, help="horizon in primitive steps (default: 3600)")
    p.add_argument("--workers", type=int, help="worker processes of the evaluation (default: 2)")
    p.add_argument("--protocol", choices=PROTOCOLS, help="coverage protocol (default: the world's, paper)")
    p.add_argument(
        "--min-explored",
        type=float,
        default=MIN_EXPLORED_PCT,
        metavar="PCT",
        help=f"stuck below this Explo %% on a small or medium map (default: {MIN_EXPLORED_PCT:g})",
    )
    p.add_argument(
        "--max-collisions",
        type=int,
        default=MAX_COLLISIONS,
        metavar="N",
        help=f"stuck above this many collisions, any map (default: {MAX_COLLISIONS})",
    )
    p.add_argument(
        "--max-stall",
        type=int,
        default=MAX_STALL_STEPS,
        metavar="STEPS",
        help=(
            "stuck when an episode ran to the horizon without progress for this many last steps "
            f"(default: {MAX_STALL_STEPS})"
        ),
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    try:
        return _main(argv)
    except InputError as exc:
        print(f"{PROG}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2


def _main(argv: Sequence[str] | None) -> int:
    args = parser().parse_args(argv)
    if args.max_collisions < 0:
        raise InputError(f"--max-collisions must be >= 0, got {args.max_collisions}")
    if args.source is not None:
        given = [f"--{k.replace('_', '-')}" for k in EVAL_DEFAULTS if getattr(args, k) is not None]
        if given:
            raise InputError(f"{' '.join(given)}: evaluation options are for --out; --from only scans a folder")
        folder = args.source
    else:
        for key, value in EVAL_DEFAULTS.items():
            if getattr(args, key) is None:
                setattr(args, key, value)
        args.maps = args.maps or ["bundled"]
        unknown = [m for m in args.methods if m not in PLANNERS]
        if unknown:
            raise InputError(f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(PLANNERS)}")
        try:
            plan = EvalPlan(args.methods, args.robots, args.maps, args.episodes, args.seed, args.max_steps, args.out)
            protocol = {"world.protocol": args.protocol} if args.protocol else None
            plan = dataclasses.replace(plan, workers=args.workers).with_settings(protocol)
            evaluate(plan, progress=sys.stderr)
        except AreaSearchError as exc:
            raise InputError(str(exc)) from None
        folder = args.out
    run = load_run(Path(folder).expanduser())
    stuck = find_stuck(run, args.maps, args.min_explored, args.max_collisions, max_stall=args.max_stall)
    stuck.sort(key=lambda s: (size_rank(s["size_class"]), s["map"], s["method"], s["robots"], s["episode"]))
    report = to_markdown(stuck, run.rows, args.min_explored, args.max_collisions, args.max_stall)
    write_text(run.folder / "stuck.csv", to_csv(stuck))
    write_text(run.folder / "stuck.md", report)
    print(report, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
