"""The commands that play episodes: ``run`` (one episode, a PNG and the metrics), ``eval`` (the
evaluation harness, :mod:`areasearch.harness.evaluate`) and ``render`` (an animation,
:mod:`areasearch.harness.animate`, or an MCAP file for Foxglove, :mod:`areasearch.harness.mcap`). Each
builds its world's typed configuration once, from ``--set``, ``--protocol`` and ``--realism``
(:func:`areasearch.cli.options.world_options`)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..config import FPS_RANGE
from ..errors import ConfigError
from ..folderlock import check_folder_path
from ..sim.scene import SIZE_CLASSES
from .options import (
    EPISODE_OPTIONS,
    MAP_HELP,
    METHOD_HELP,
    WEIGHTS_HELP,
    Subparsers,
    add_max_steps,
    add_protocol,
    add_realism,
    add_robots,
    add_set,
    fps_type,
    output_file,
    positive_int,
    print_json,
    seed_type,
    world_options,
)

MCAP_SUFFIX = ".mcap"
"""``render --out`` with this suffix writes the episode as MCAP (:mod:`areasearch.harness.mcap`), not an animation."""

# ---------------------------------------------------------------------------------- run


def cmd_run(args: argparse.Namespace) -> int:
    """One search episode with a goal planner; PNG of the last frame and metrics as JSON."""
    from ..harness.evaluate import make_env, play_episode
    from ..planners import choose_planner
    from ..sim.render import draw_world, save_png

    out = Path(args.out)
    output_file(out, "picture")
    world = world_options(args.set, EPISODE_OPTIONS, args.protocol, args.realism)
    choice = choose_planner(args.method, args.weights)
    env = make_env(args.map, args.robots, args.seed, args.max_steps, world.config())
    trace = play_episode(env, choice.planner, args.seed, sys.stderr, "run")
    played = env.world
    assert played.scene is not None
    save_png(draw_world(played, goals=env.goals, candidates=env.candidates), out)
    settings = world.given
    summary = {
        "map": played.scene.name,
        "size_class": played.scene.size_class,
        "free_area_m2": round(played.scene.free_area_m2, 2),
        "robots": args.robots,
        "method": choice.method,
        **choice.record(),
        "seed": args.seed,
        **({"realism": world.realism} if world.realism != "none" else {}),
        **({"settings": settings} if settings else {}),
        "decisions": len(trace.steps) - 1,
        **played.metrics.as_dict(),
        **_map_error(trace.map_quality),
        "picture": str(out),
    }
    print_json(summary)
    return 0


def _map_error(quality: Any) -> dict[str, Any]:
    """The team map's error at the end and its parts (imperfect worlds: :mod:`areasearch.sim.mapquality`)."""
    if quality is None:
        return {}
    parts = {name: round(value, 2) for name, value in quality.parts_pct().items()}
    return {"map_error_pct": quality.error_pct, "map_error_parts_pct": parts}


def add_run_parser(sub: Subparsers) -> argparse.ArgumentParser:
    run = sub.add_parser(
        "run", help="run one search episode with a goal planner on a map; write a PNG and print the metrics"
    )
    run.add_argument("--map", default="robotathome_sarmis", help=MAP_HELP)
    add_robots(run)
    run.add_argument("--method", help=METHOD_HELP)
    run.add_argument("--weights", metavar="PREFIX", help=WEIGHTS_HELP)
    add_max_steps(run)
    run.add_argument("--seed", type=seed_type, default=0, help="random seed (default 0)")
    run.add_argument("--out", default="episode.png", help="final-frame PNG (default episode.png)")
    add_protocol(run)
    add_realism(run)
    add_set(run, "robot.radius_m=0.2 --set targets.count=50")
    run.set_defaults(func=cmd_run)
    return run


# ---------------------------------------------------------------------------------- eval


def cmd_eval(args: argparse.Namespace) -> int:
    """Evaluate goal planners (resumable); write episodes.csv, curves.jsonl, summaries and curves.png."""
    from ..harness.evaluate import EvalPlan, evaluate
    from ..harness.mcap import parse_selector

    check_folder_path(Path(args.out).expanduser(), "output path")
    world = world_options(args.set, EPISODE_OPTIONS, args.protocol, args.realism)
    policies = _policies(args.policy)
    record = [parse_selector(text) for text in args.record_mcap]
    plan = EvalPlan(
        methods=args.methods,
        robots=args.robots,
        maps=args.maps,
        episodes=args.episodes,
        seed=args.seed,
        max_steps=args.max_steps,
        out=args.out,
        config=world.config(checked=False),  # checked with the other arguments
        settings=tuple(sorted(world.given.items())),
        realism=world.realism,
        policies=policies,
        sizes=args.sizes,
        maps_per_size=args.maps_per_size,
        workers=args.workers,
        backend=args.backend,
        address=args.address,
        replace=args.replace,
    )
    evaluate(plan, progress=sys.stderr, record=record)
    out = Path(args.out)
    print((out / "summary.md").read_text())
    print(f"results in {out}: episodes.csv, curves.jsonl, summary.md, summary.json, summary.tex, curves.png")
    if record:
        from ..harness.mcap import LAYOUT, RECORD_FOLDER

        print(f"recorded episodes in {out / RECORD_FOLDER} (MCAP); a Foxglove layout for them: {LAYOUT}")
    return 0


def _policies(entries: Sequence[str]) -> dict[str, str]:
    """``--policy NAME=PREFIX`` entries as a dict; ConfigError for a malformed or repeated one."""
    out: dict[str, str] = {}
    for entry in entries:
        name, sep, prefix = entry.partition("=")
        if not sep or not name or not prefix:
            raise ConfigError(f"--policy takes NAME=PREFIX (e.g. dahgnn-s1=runs/dahgnn-s1/policy), got {entry!r}")
        if name in out:
            raise ConfigError(f"--policy {name} is given twice")
        out[name] = prefix
    return out


def add_eval_parser(sub: Subparsers) -> argparse.ArgumentParser:
    ev = sub.add_parser(
        "eval",
        help="evaluate goal planners over maps, team sizes and seeded episodes; write the paper's tables",
        description="Every (map, team size, episode) is played by every method with the same seed. Re-running "
        "the same command resumes: finished episodes in --out are kept (other settings are refused).",
    )
    ev.add_argument("--methods", nargs="+", required=True, metavar="METHOD", help="planner names (areasearch.planners)")
    ev.add_argument(
        "--policy",
        action="append",
        default=[],
        metavar="NAME=PREFIX",
        help="a learned method of your own: NAME (listed in --methods) plays the policy PREFIX.safetensors + "
        "PREFIX.json, e.g. a training run's runs/dahgnn-s1/policy (repeatable)",
    )
    add_robots(ev, several=True)
    ev.add_argument(
        "--maps",
        nargs="+",
        default=["bundled"],
        metavar="MAP",
        help="'bundled' (all bundled maps), 'bundled:train', 'bundled:val' or 'bundled:test' (the maps of one "
        "split; results go on bundled:test, see 'areasearch maps --split test'), bundled map ids, map folders "
        "with index.json, PNGs in them, ROS .yaml (default bundled)",
    )
    ev.add_argument("--sizes", nargs="+", choices=SIZE_CLASSES, help="only these size classes")
    ev.add_argument(
        "--maps-per-size", type=positive_int, metavar="N", help="N maps per size class, evenly spaced by id"
    )
    ev.add_argument("--episodes", type=positive_int, default=5, help="episodes per (map, team size) (default 5)")
    ev.add_argument("--seed", type=seed_type, default=0, help="run seed; episode seeds derive from it (default 0)")
    add_max_steps(ev)
    ev.add_argument("--out", required=True, help="results folder (created; an existing one is resumed)")
    ev.add_argument(
        "--replace",
        nargs="+",
        default=[],
        metavar="METHOD",
        help="play METHOD (a shipped policy or a --policy name, listed in --methods) again where OUT holds its "
        "episodes played with other weights (a policy retrained and shipped again) or with weights OUT has no "
        "record of: its old episodes move to OUT/replaced/N/ (a resume without it is refused)",
    )
    ev.add_argument(
        "--workers", type=positive_int, default=1, help="worker processes, or CPUs of a local Ray (default 1)"
    )
    ev.add_argument(
        "--backend", choices=("local", "ray"), default="local", help="episodes in local processes or Ray tasks"
    )
    ev.add_argument("--address", default=None, help="with --backend ray: an existing Ray cluster (default: start one)")
    ev.add_argument(
        "--record-mcap",
        nargs="+",
        default=[],
        metavar="SELECTOR",
        help="also record the episodes a SELECTOR matches as MCAP files for Foxglove, OUT/episodes/METHOD/"
        "MAP-rR-eK.mcap: 'all', or KEY=VALUE[,KEY=VALUE...] with keys method, map, robots, episode (e.g. "
        "method=greedy,episode=0); changes no result; needs pip install 'areasearch[mcap]'",
    )
    add_protocol(ev)
    add_realism(ev)
    add_set(ev, "targets.count=50", "a world setting of every episode (recorded in config.json)")
    ev.set_defaults(func=cmd_eval)
    return ev


# ---------------------------------------------------------------------------------- render


def cmd_render(args: argparse.Namespace) -> int:
    """One goal-planner episode as an animation plus its last frame; metrics as JSON."""
    from ..harness.animate import compare_episodes, render_episode

    if args.method is None and not args.methods and args.weights is None:
        raise ConfigError("name the planner: --method NAME, --methods NAME NAME..., or --weights PREFIX")
    world = world_options(args.set, EPISODE_OPTIONS, args.protocol, args.realism)
    if Path(args.out).suffix.lower() == MCAP_SUFFIX:
        return _render_mcap(args, world.applied)
    options = {
        "max_steps": args.max_steps,
        "every": args.every,
        "fps": args.fps,
        "settings": world.applied,  # the --realism preset's under the --set ones
        "weights": args.weights,
        "progress": sys.stderr,
        "belief": args.belief,
    }
    if args.methods:
        result = compare_episodes(args.methods, args.map, args.robots, args.seed, args.out, **options)
        print(result.pop("table"))
        print_json(result)
        return 0
    summary = render_episode(args.method, args.map, args.robots, args.seed, args.out, **options)
    print_json(summary)
    return 0


def _render_mcap(args: argparse.Namespace, settings: dict[str, Any]) -> int:
    """``render --out X.mcap``: one episode as an MCAP file for Foxglove; metrics and paths as JSON."""
    from ..harness.animate import record_episode

    if args.methods:
        raise ConfigError(
            "an .mcap file holds one episode: name one --method (--methods plays several side by side in a .gif "
            "or .mp4)"
        )
    if args.belief is not None:
        raise ConfigError(
            "--belief draws a second panel in an animation; an .mcap file holds the team's map (/map) and, on an "
            "imperfect world, the truth beside it (/map/truth)"
        )
    summary = record_episode(
        args.method,
        args.map,
        args.robots,
        args.seed,
        args.out,
        max_steps=args.max_steps,
        every=args.every,
        settings=settings,  # the --realism preset's under the --set ones
        weights=args.weights,
        progress=sys.stderr,
    )
    print_json(summary)
    return 0


def add_render_parser(sub: Subparsers) -> argparse.ArgumentParser:
    rd = sub.add_parser(
        "render",
        help="animate one goal-planner episode (GIF, or MP4 with ffmpeg), or write it as MCAP for Foxglove; print "
        "metrics",
    )
    which = rd.add_mutually_exclusive_group()
    which.add_argument("--method", help="goal planner ('areasearch methods' lists them, plug-ins included)")
    which.add_argument(
        "--methods",
        nargs="+",
        metavar="METHOD",
        help="several planners on the same episode, side by side, with a comparison table (.md beside --out)",
    )
    rd.add_argument(
        "--weights",
        metavar="PREFIX",
        help=WEIGHTS_HELP + "; with --methods, played by the one learned method among them",
    )
    rd.add_argument("--map", default="robotathome_sarmis", help=MAP_HELP)
    add_robots(rd)
    rd.add_argument(
        "--seed", type=seed_type, default=0, help="episode seed (an episodes.csv seed replays that episode)"
    )
    add_max_steps(rd)
    rd.add_argument(
        "--every",
        type=positive_int,
        default=40,
        help="a frame every K primitive steps (default 40); in an .mcap file, a frame of the map",
    )
    rd.add_argument(
        "--fps",
        type=fps_type,
        default=8.0,
        help=f"frames per second of the animation, {FPS_RANGE[0]:g}-{FPS_RANGE[1]:g} (default 8)",
    )
    rd.add_argument(
        "--out",
        default="episode.gif",
        help="animation .gif or .mp4 (last frame beside it as .png), or .mcap: the episode for Foxglove (map, "
        "robots, goals, targets, truth, metrics; needs pip install 'areasearch[mcap]')",
    )
    rd.add_argument(
        "--belief",
        metavar="team|N",
        help="a second panel in every frame: the team's map at the believed poses (team) or robot N's own map "
        "(0-based; its own under limited communication), beside the truth on the left, with its map error",
    )
    add_protocol(rd)
    add_realism(rd)
    add_set(rd, "targets.count=50")
    rd.set_defaults(func=cmd_render)
    return rd
