"""The ``areasearch`` command line.

Subcommands: ``run`` (one search episode on a map, writes a PNG, prints the metrics), ``maps``
(the bundled maps), ``eval`` (goal planners over maps, team sizes and seeded episodes: the paper's
tables, :mod:`areasearch.evaluate`), ``render`` (one goal-planner episode as a GIF/MP4,
:mod:`areasearch.animate`) and ``assign`` (goals for your own robots on your own map, JSON in and out,
:mod:`areasearch.assign`). Bad input ends with one ``areasearch: error: ...`` line on stderr and exit
status 2, never a traceback; outputs are written atomically, so nothing already there is lost.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from . import __version__
from .config import MAX_ROBOTS
from .errors import AreaSearchError
from .evaluate import play_episode
from .goal_env import AreaSearchEnv
from .planners import PLANNERS, make_planner
from .render import draw_world, save_png
from .scene import bundled_index


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _robots(text: str) -> int:
    value = _positive_int(text)
    if value > MAX_ROBOTS:
        raise argparse.ArgumentTypeError(f"at most {MAX_ROBOTS} robots, got {value}")
    return value


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer seed, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer seed, got {value}")
    return value


def _settings(pairs: Sequence[str] | None) -> dict[str, Any]:
    """``KEY=VALUE`` strings -> config overrides; values are read as JSON (numbers, true/false) or text."""
    settings: dict[str, Any] = {}
    for pair in pairs or ():
        key, sep, text = pair.partition("=")
        if not sep or not key:
            raise AreaSearchError(f"--set expects KEY=VALUE (e.g. robot.radius_m=0.2), got {pair!r}")
        try:
            settings[key] = json.loads(text)
        except json.JSONDecodeError:
            settings[key] = text
    return settings


def _output_file(path: Path, what: str) -> None:
    if path.is_dir():
        raise AreaSearchError(f"{path}: {what} path is a folder; give a file name")
    if not path.parent.exists():
        raise AreaSearchError(f"{path.parent}: folder for the {what} does not exist")


def cmd_run(args: argparse.Namespace) -> int:
    """One search episode with a goal planner; PNG of the last frame and metrics as JSON."""
    out = Path(args.out)
    _output_file(out, "picture")
    settings = _settings(args.set)
    for key in ("num_robots", "max_steps"):
        if key in settings:
            raise AreaSearchError(f"--set {key}=... is not allowed here; use --robots / --steps")
    planner = make_planner(args.method)
    env = AreaSearchEnv(map=args.map, num_robots=args.robots, seed=args.seed, max_steps=args.steps, **settings)
    trace = play_episode(env, planner, args.seed)
    world = env.world
    assert world.scene is not None
    save_png(draw_world(world, goals=env.goals, candidates=env.candidates), out)
    summary = {
        "map": world.scene.name,
        "size_class": world.scene.size_class,
        "free_area_m2": round(world.scene.free_area_m2, 2),
        "robots": args.robots,
        "method": args.method,
        "seed": args.seed,
        "decisions": len(trace.steps) - 1,
        **world.metrics.as_dict(),
        "picture": str(out),
    }
    print(json.dumps(summary, indent=2))
    return 0


def cmd_maps(args: argparse.Namespace) -> int:
    """List the bundled maps: id, size class, free area, derived or whole building, license."""
    entries = bundled_index()
    if args.size:
        entries = [e for e in entries if e["size_class"] in args.size]
    if args.json:
        print(json.dumps(entries, indent=2))
        return 0
    print(f"{'id':34} {'class':7} {'free m²':>8}  {'cells':>11}  kind")
    for e in sorted(entries, key=lambda e: (("small", "medium", "large").index(e["size_class"]), e["free_area_m2"])):
        kind = "room group" if e.get("derived") else "building"
        print(f"{e['id']:34} {e['size_class']:7} {e['free_area_m2']:8.1f}  {e['width']:>5}x{e['height']:<5}  {kind}")
    print(f"{len(entries)} maps; licenses and sources: `areasearch maps --json` or the package's maps/README.md")
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    """Evaluate goal planners (resumable); write episodes.csv, curves.jsonl, summaries and curves.png."""
    from .evaluate import evaluate

    evaluate(
        args.methods,
        args.robots,
        args.maps,
        args.episodes,
        args.seed,
        args.max_steps,
        args.out,
        workers=args.workers,
        sizes=args.sizes,
        maps_per_size=args.maps_per_size,
        backend=args.backend,
        address=args.address,
    )
    out = Path(args.out)
    print((out / "summary.md").read_text())
    print(f"results in {out}: episodes.csv, curves.jsonl, summary.md, summary.json, summary.tex, curves.png")
    return 0


def cmd_assign(args: argparse.Namespace) -> int:
    """Goals for your robots on your own map: JSON in (robots, targets), JSON out (:mod:`areasearch.assign`)."""
    from .assign import assign_goals, assignments_json, dumps, read_robots, read_targets
    from .report import write_text

    out = Path(args.out) if args.out else None
    if out is not None:
        _output_file(out, "assignment")
    robots = read_robots(args.robots)
    target_ids, targets = read_targets(args.targets) if args.targets else ([], None)
    assignments = assign_goals(
        args.map,
        robots.poses,
        args.method,
        targets,
        robots.past_positions,
        robots.past_goals,
        resolution=args.resolution,
        origin=args.origin,
        radius_m=args.radius_m,
        sensor_range_m=args.sensor_range_m,
        seed=args.seed,
        planner_settings={"weights": args.weights} if args.weights else None,
        robot_names=robots.ids,
    )
    text = dumps(assignments_json(assignments, robots.ids, target_ids, args.method))
    if out is not None:
        write_text(out, text)
    else:
        sys.stdout.write(text)
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    """One goal-planner episode as an animation plus its last frame; metrics as JSON."""
    from .animate import compare_episodes, render_episode

    if not 1 <= args.robots <= MAX_ROBOTS:
        raise AreaSearchError(f"--robots must be from 1 to {MAX_ROBOTS}, got {args.robots}")
    if args.methods:
        result = compare_episodes(
            args.methods,
            args.map,
            args.robots,
            args.seed,
            args.out,
            max_steps=args.max_steps,
            every=args.every,
            fps=args.fps,
        )
        print(result.pop("table"))
        print(json.dumps(result, indent=2))
        return 0
    summary = render_episode(
        args.method,
        args.map,
        args.robots,
        args.seed,
        args.out,
        max_steps=args.max_steps,
        every=args.every,
        fps=args.fps,
    )
    print(json.dumps(summary, indent=2))
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    """PPO training of a DA-HGNN / NCM policy (resumable); see :mod:`areasearch.train`."""
    from .train import load_config, parse_overrides, train

    config = load_config(args.config, parse_overrides(args.set or ()))
    result = train(
        config,
        args.out,
        resume=args.resume,
        device=args.device,
        workers=args.workers,
        backend=args.backend,
        address=args.address,
        stop_after=args.iterations,
    )
    print(
        f"{args.out}: {result.iterations} iterations, {result.decisions:,} decisions, "
        f"best validation Cover% AUC {result.best_score:.2f}, {result.wall_s / 60:.1f} min"
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="areasearch", description="Multi-robot collaborative area search (explore and cover), after DA-HGNN."
    )
    parser.add_argument("--version", action="version", version=f"areasearch {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    run = sub.add_parser(
        "run", help="run one search episode with a goal planner on a map; write a PNG and print the metrics"
    )
    run.add_argument(
        "--map",
        default="robotathome_sarmis",
        help="bundled map id, PNG in a map folder, map folder, ROS .yaml, or procedural:<class>",
    )
    run.add_argument("--robots", type=_robots, default=3, help="team size, 1-8 (default 3)")
    run.add_argument("--method", default="greedy", help=f"goal planner: {', '.join(PLANNERS)} (default greedy)")
    run.add_argument("--steps", type=_positive_int, default=3600, help="horizon in primitive steps (default 3600)")
    run.add_argument("--seed", type=_seed, default=0, help="random seed (default 0)")
    run.add_argument("--out", default="episode.png", help="final-frame PNG (default episode.png)")
    run.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override a world setting, e.g. --set robot.radius_m=0.2 --set targets.count=50 (repeatable)",
    )
    run.set_defaults(func=cmd_run)

    maps = sub.add_parser("maps", help="list the bundled maps with size class and free area")
    maps.add_argument("--size", nargs="+", choices=("small", "medium", "large"), help="only these size classes")
    maps.add_argument("--json", action="store_true", help="print the full index entries as JSON")
    maps.set_defaults(func=cmd_maps)

    ev = sub.add_parser(
        "eval",
        help="evaluate goal planners over maps, team sizes and seeded episodes; write the paper's tables",
        description="Every (map, team size, episode) is played by every method with the same seed. Re-running "
        "the same command resumes: finished episodes in --out are kept.",
    )
    ev.add_argument("--methods", nargs="+", required=True, metavar="METHOD", help="planner names (areasearch.planners)")
    ev.add_argument("--robots", nargs="+", type=int, default=[3], metavar="R", help="team sizes, 1-8 (default 3)")
    ev.add_argument(
        "--maps",
        nargs="+",
        default=["bundled"],
        metavar="MAP",
        help="'bundled' (all bundled maps), bundled map ids, map folders with index.json, PNGs in them, ROS .yaml",
    )
    ev.add_argument("--sizes", nargs="+", choices=("small", "medium", "large"), help="only these size classes")
    ev.add_argument("--maps-per-size", type=int, metavar="N", help="N maps per size class, evenly spaced by id")
    ev.add_argument("--episodes", type=int, default=5, help="episodes per (map, team size) (default 5)")
    ev.add_argument("--seed", type=int, default=0, help="run seed; episode seeds derive from it (default 0)")
    ev.add_argument("--max-steps", type=int, default=3600, help="horizon in primitive steps (default 3600)")
    ev.add_argument("--out", required=True, help="results folder (created; an existing one is resumed)")
    ev.add_argument("--workers", type=int, default=1, help="worker processes, or CPUs of a local Ray (default 1)")
    ev.add_argument(
        "--backend", choices=("local", "ray"), default="local", help="episodes in local processes or Ray tasks"
    )
    ev.add_argument("--address", default=None, help="with --backend ray: an existing Ray cluster (default: start one)")
    ev.set_defaults(func=cmd_eval)

    asg = sub.add_parser(
        "assign",
        help="goals for your robots on your own (partial) map: robots JSON in, goals and paths JSON out",
        description="One long-term goal per robot from a goal planner, on an occupancy map as SLAM makes it "
        "(unknown cells unexplored), with the planned path; poses and goals in metres in the map frame.",
    )
    asg.add_argument("--map", required=True, help="ROS map_server .yaml, or a .png/.pgm map with --resolution")
    asg.add_argument("--robots", required=True, help='robots JSON: {"robots": [{"id", "x", "y", "yaw"}, ...]}')
    asg.add_argument("--targets", help='known targets JSON: {"targets": [{"id", "x", "y"}, ...]}')
    asg.add_argument("--method", default="greedy", help=f"goal planner: {', '.join(PLANNERS)} (default greedy)")
    asg.add_argument("--weights", metavar="PREFIX", help="learned planner: PREFIX.safetensors + PREFIX.json")
    asg.add_argument("--resolution", type=float, help="metres per cell of a .png/.pgm map")
    asg.add_argument(
        "--origin", type=float, nargs=2, metavar=("X", "Y"), help="map-frame x y of the image's lower-left corner"
    )
    asg.add_argument("--radius-m", type=float, help="robot footprint radius, metres (default 0.18)")
    asg.add_argument("--sensor-range-m", type=float, help="sensor range for information gain, metres (default 3.2)")
    asg.add_argument("--seed", type=_seed, default=0, help="seed of the planner's random draws (default 0)")
    asg.add_argument("--out", help="write the JSON to this file (atomically) instead of stdout")
    asg.set_defaults(func=cmd_assign)

    rd = sub.add_parser("render", help="animate one goal-planner episode (GIF, or MP4 with ffmpeg); print metrics")
    which = rd.add_mutually_exclusive_group(required=True)
    which.add_argument("--method", help="planner name (areasearch.planners)")
    which.add_argument(
        "--methods",
        nargs="+",
        metavar="METHOD",
        help="several planners on the same episode, side by side, with a comparison table (.md beside --out)",
    )
    rd.add_argument("--map", default="robotathome_sarmis", help="bundled map id, PNG in a map folder, ROS .yaml, ...")
    rd.add_argument("--robots", type=int, default=3, help="team size, 1-8 (default 3)")
    rd.add_argument("--seed", type=_seed, default=0, help="episode seed (an episodes.csv seed replays that episode)")
    rd.add_argument("--max-steps", type=int, default=3600, help="horizon in primitive steps (default 3600)")
    rd.add_argument("--every", type=int, default=40, help="a frame every K primitive steps (default 40)")
    rd.add_argument("--fps", type=float, default=8.0, help="frames per second of the animation (default 8)")
    rd.add_argument("--out", default="episode.gif", help="animation .gif or .mp4; last frame beside it as .png")
    rd.set_defaults(func=cmd_render)

    tr = sub.add_parser(
        "train",
        help="train a DA-HGNN / NCM goal planner with PPO (resumable); writes checkpoints, logs and the policy",
        description="Re-running with --resume continues a killed run from its last checkpoint; without "
        "--resume an existing run folder is never overwritten.",
    )
    tr.add_argument("--config", required=True, help="training config, TOML (configs/*.toml) or a run's config.json")
    tr.add_argument("--out", required=True, help="run folder, e.g. runs/dahgnn")
    tr.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    tr.add_argument("--device", choices=("cpu", "cuda"), default="cpu", help="device of the learner (default cpu)")
    tr.add_argument("--workers", type=int, default=None, help="rollout worker processes (default: one per core)")
    tr.add_argument("--backend", choices=("local", "ray"), default="local", help="rollout workers (default local)")
    tr.add_argument("--address", default=None, help="with --backend ray: address of an existing Ray cluster")
    tr.add_argument("--iterations", type=_positive_int, default=None, help="stop after N iterations (resumable)")
    tr.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="override a config setting, e.g. --set ppo.epochs=2"
    )
    tr.set_defaults(func=cmd_train)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except AreaSearchError as exc:
        print(f"areasearch: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("areasearch: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `areasearch maps | head`
        sys.stdout = open(os.devnull, "w")
        return 1


if __name__ == "__main__":
    sys.exit(main())
