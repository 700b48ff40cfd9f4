"""The ``areasearch`` command line.

Subcommands:

* ``run``: one search episode on a map with a goal planner; writes a PNG, prints the metrics.
* ``maps``: the bundled maps (size class, free area, license).
* ``eval``: goal planners over maps, team sizes and seeded episodes, resumable: the paper's tables
  (:mod:`areasearch.harness.evaluate`).
* ``render``: one goal-planner episode, or several planners on the same episode side by side, as a
  GIF / MP4 (:mod:`areasearch.harness.animate`).
* ``assign``: goals for your own robots on your own map, JSON in and out (:mod:`areasearch.service.assign`).
* ``train``: PPO training of a DA-HGNN / NCM goal planner, resumable (:mod:`areasearch.training.train`).
* ``serve``: ``assign`` as a warm HTTP JSON service for robot stacks (:mod:`areasearch.service.serve`).
* ``methods``: every goal planner with its origin: built in, shipped policy, plug-in
  (:func:`areasearch.planners.describe_planners`).

``run``, ``render``, ``assign`` and ``serve`` take ``--weights PREFIX``: a learned method
(``--method``) plays your own weights, or without ``--method`` the network the weights describe
(:func:`areasearch.planners.choose_planner`); the output names the weights' SHA-256.

The commands share their option names and checks: ``--robots`` (team size, 1-8), ``--max-steps``
(horizon in primitive steps), ``--seed``, ``--workers``, and ``--set KEY=VALUE`` (repeatable) on
every command that builds a world (:func:`areasearch.config.parse_settings`; world keys such as
``robot.radius_m`` or ``targets.count``, training-config keys for ``train``), and ``--protocol`` (the
coverage rule, :data:`areasearch.config.PROTOCOLS`) on ``run``, ``render`` and ``eval``. Progress of ``run``,
``render``, ``eval`` and ``train`` goes to stderr: a bar on a terminal, a plain line every 10 s otherwise
(:mod:`areasearch.progress`). Results printed as JSON have their numbers rounded to what they mean
(:func:`areasearch.harness.report.json_ready`). Bad input ends with one ``areasearch: error: ...`` line on stderr
and exit status 2 (after the usage of the command for a malformed command line), never a traceback;
outputs are written atomically, so nothing already there is lost.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NoReturn

from ._version import __version__
from .config import (
    CAMERA_LIMITS,
    FPS_RANGE,
    MAX_ROBOTS,
    PROTOCOLS,
    ROBOT_LIMITS,
    parse_settings,
    search_key,
    search_settings,
)
from .errors import AreaSearchError, ConfigError
from .folderlock import check_file_path, check_folder_path
from .inputs import WRITE_ERRORS, clip_words, int_digits_message, is_int_digits_error, short
from .sim.scene import MAX_CELL_M, MAX_ORIGIN_M, MIN_CELL_M, bundled_index

Subparsers = Any  # argparse's _SubParsersAction, private in typeshed's view

# ---------------------------------------------------------------------------------- the parser


class _Once(argparse.Action):
    """An option given a second time is refused, naming it (rather than the last one silently winning)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        given = vars(namespace).setdefault("_given_options", set())
        if self.dest in given:
            parser.error(f"argument {'/'.join(self.option_strings)}: given twice; give it once")
        given.add(self.dest)
        super().__call__(parser, namespace, values, option_string)


class _StoreOnce(_Once, argparse._StoreAction):
    """``store``, once."""


class _StoreTrueOnce(_Once, argparse._StoreTrueAction):
    """``store_true``, once."""


class Parser(argparse.ArgumentParser):
    """The parser of the command and its subcommands: every option but the repeatable ``--set`` may
    be given once (``--methods a --methods b`` is refused, naming ``--methods``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.commands: dict[str, argparse.ArgumentParser] = {}
        """The subcommands' parsers by name (set by :func:`build_parser`)."""
        self.register("action", None, _StoreOnce)
        self.register("action", "store", _StoreOnce)
        self.register("action", "store_true", _StoreTrueOnce)

    def parse_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> argparse.Namespace:
        """argparse's, but arguments that no option takes are refused by the subcommand they follow, so
        the usage printed is that subcommand's."""
        parsed, extra = self.parse_known_args(args, namespace)
        if extra:
            self.commands.get(getattr(parsed, "command", None) or "", self).error(
                f"unrecognized arguments: {' '.join(extra)}"
            )
        return parsed

    def error(self, message: str) -> NoReturn:
        """A malformed command line: the usage of the (sub)command, which names it, then one
        ``areasearch: error: ...`` line, the last line of every other bad input too; exit status 2."""
        self.print_usage(sys.stderr)
        self.exit(2, f"{_error_line(message)}\n")


# ---------------------------------------------------------------------------------- argument types


def _integer(minimum: int, what: str) -> Callable[[str], int]:
    """An argparse type: an integer >= ``minimum``, refused as "expected <what>, got ..."."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError as exc:
            if is_int_digits_error(exc):
                raise argparse.ArgumentTypeError(f"expected {what}, got {int_digits_message()}") from None
            raise argparse.ArgumentTypeError(f"expected {what}, got {short(text)}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected {what}, got {value}")
        return value

    return parse


def _real(low: float, high: float, what: str, *, low_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number in [``low``, ``high``] (``(low, high]`` with ``low_open``),
    refused, naming the option, as "expected a number in [low, high] (<what>), got ..." (``inf``, ``nan``,
    ``1e308`` and ``1e-9`` frames per second never reach the code that would divide by them or turn
    them into array sizes)."""
    bounds = f"{'(' if low_open else '['}{low:g}, {high:g}]"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number in {bounds} ({what}), got {short(text)}") from None
        if not math.isfinite(value) or value < low or (low_open and value == low) or value > high:
            raise argparse.ArgumentTypeError(f"expected a number in {bounds} ({what}), got {short(text)}")
        return value

    return parse


_positive_int = _integer(1, "a positive integer")
"""An integer >= 1 (counts, horizons, frame spacing)."""
_non_negative_int = _integer(0, "a non-negative integer")
"""An integer >= 0 (``train --workers``: 0 plays in this process)."""
_seed = _integer(0, "a non-negative integer seed")
"""A seed, an integer >= 0."""


_fps = _real(*FPS_RANGE, "frames per second")
"""``render --fps``: a GIF stores a frame's duration in hundredths of a second (at most 655 s)."""
_resolution = _real(MIN_CELL_M, MAX_CELL_M, "metres per cell")
"""``assign --resolution``: the cell sizes a map may have (:func:`areasearch.sim.scene.check_resolution`)."""
_origin = _real(-MAX_ORIGIN_M, MAX_ORIGIN_M, "metres")
"""``assign --origin``: a map's corner within :data:`areasearch.sim.scene.MAX_ORIGIN_M` of the frame's zero."""
_radius = _real(0.0, ROBOT_LIMITS["radius_m"], "metres", low_open=True)
"""``assign --radius-m``: the footprint radii :class:`areasearch.config.RobotConfig` takes."""
_sensor_range = _real(0.0, CAMERA_LIMITS["max_range_m"], "metres", low_open=True)
"""``assign --sensor-range-m``: the ranges :class:`areasearch.config.CameraConfig` takes."""


def _robots(text: str) -> int:
    """A team size, 1 to :data:`~areasearch.config.MAX_ROBOTS`."""
    value = _positive_int(text)
    if value > MAX_ROBOTS:
        raise argparse.ArgumentTypeError(f"at most {MAX_ROBOTS} robots, got {value}")
    return value


# ---------------------------------------------------------------------------------- shared options

MAP_HELP = "bundled map id, PNG in a map folder, map folder, ROS .yaml, or procedural:<class>"
METHOD_HELP = "goal planner (default greedy; 'areasearch methods' lists them, plug-ins included)"
WEIGHTS_HELP = (
    "your own weights, PREFIX.safetensors + PREFIX.json (e.g. runs/dahgnn/policy): played by the learned "
    "--method, or without --method by the network they describe"
)
EPISODE_OPTIONS = {"world.num_robots": "--robots", "world.max_steps": "--max-steps"}
"""World settings that the commands playing episodes take as options of their own, not by ``--set``."""


def _add_robots(parser: argparse.ArgumentParser, *, several: bool = False) -> None:
    if several:
        parser.add_argument(
            "--robots", nargs="+", type=_robots, default=[3], metavar="R", help="team sizes, 1-8 (default 3)"
        )
    else:
        parser.add_argument("--robots", type=_robots, default=3, help="team size, 1-8 (default 3)")


def _add_max_steps(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--max-steps", type=_positive_int, default=3600, metavar="N", help="horizon in primitive steps (default 3600)"
    )


def _add_set(parser: argparse.ArgumentParser, example: str, what: str = "a world setting") -> None:
    parser.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help=f"override {what}, e.g. --set {example} (repeatable; values read as JSON numbers, true/false, lists)",
    )


def _add_protocol(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--protocol",
        choices=tuple(PROTOCOLS),
        default=None,
        help="coverage protocol: paper (default; a robot centre passes over the target's cell) or passby "
        "(within 0.3 m at the end of a step: a looser rule, for results measured under it)",
    )


def _world_settings(pairs: Sequence[str] | None, own: Mapping[str, str], protocol: str | None = None) -> dict[str, Any]:
    """The ``--set`` pairs of a command that builds a world, by their full keys; a key that the command
    sets by an option of its own (``own``: full key -> option) is refused, naming the option. A
    ``--protocol`` given joins them as ``world.protocol``."""
    settings = parse_settings(pairs or ())
    for key in settings:
        option = own.get(search_key(key))
        if option is not None:
            raise ConfigError(f"--set {key}=... is not allowed here; use {option}")
    resolved = search_settings(settings)
    if protocol is not None:
        if "world.protocol" in resolved:
            raise ConfigError("give the protocol once: --protocol or --set protocol=..., not both")
        resolved["world.protocol"] = protocol
    return resolved


def _output_file(path: Path, what: str) -> None:
    check_file_path(path, what)


def _print_json(doc: Mapping[str, Any]) -> None:
    """Print a command's result as indented JSON, its numbers rounded to what they mean
    (:func:`areasearch.harness.report.json_ready`); the ``settings`` given are echoed as given."""
    from .harness.report import json_ready

    rounded = json_ready(dict(doc))
    print(json.dumps({k: doc[k] if k == "settings" else rounded[k] for k in doc}, indent=2))


# ---------------------------------------------------------------------------------- run


def cmd_run(args: argparse.Namespace) -> int:
    """One search episode with a goal planner; PNG of the last frame and metrics as JSON."""
    from .harness.evaluate import make_env, play_episode
    from .planners import choose_planner
    from .sim.render import draw_world, save_png

    out = Path(args.out)
    _output_file(out, "picture")
    settings = _world_settings(args.set, EPISODE_OPTIONS, args.protocol)
    choice = choose_planner(args.method, args.weights)
    env = make_env(args.map, args.robots, args.seed, args.max_steps, settings)
    trace = play_episode(env, choice.planner, args.seed, sys.stderr, "run")
    world = env.world
    assert world.scene is not None
    save_png(draw_world(world, goals=env.goals, candidates=env.candidates), out)
    summary = {
        "map": world.scene.name,
        "size_class": world.scene.size_class,
        "free_area_m2": round(world.scene.free_area_m2, 2),
        "robots": args.robots,
        "method": choice.method,
        **choice.record(),
        "seed": args.seed,
        **({"settings": settings} if settings else {}),
        "decisions": len(trace.steps) - 1,
        **world.metrics.as_dict(),
        "picture": str(out),
    }
    _print_json(summary)
    return 0


def add_run_parser(sub: Subparsers) -> argparse.ArgumentParser:
    run = sub.add_parser(
        "run", help="run one search episode with a goal planner on a map; write a PNG and print the metrics"
    )
    run.add_argument("--map", default="robotathome_sarmis", help=MAP_HELP)
    _add_robots(run)
    run.add_argument("--method", help=METHOD_HELP)
    run.add_argument("--weights", metavar="PREFIX", help=WEIGHTS_HELP)
    _add_max_steps(run)
    run.add_argument("--seed", type=_seed, default=0, help="random seed (default 0)")
    run.add_argument("--out", default="episode.png", help="final-frame PNG (default episode.png)")
    _add_protocol(run)
    _add_set(run, "robot.radius_m=0.2 --set targets.count=50")
    run.set_defaults(func=cmd_run)
    return run


# ---------------------------------------------------------------------------------- maps


def cmd_maps(args: argparse.Namespace) -> int:
    """List the bundled maps: id, size class, split, free area, derived or whole building, license."""
    from .sim.splits import SPLITS, split_maps

    split_of = {map_id: split for split in SPLITS for map_id in split_maps(split)}
    entries = [{**e, "split": split_of[e["id"]]} for e in bundled_index()]
    if args.size:
        entries = [e for e in entries if e["size_class"] in args.size]
    if args.split:
        entries = [e for e in entries if e["split"] in args.split]
    if args.json:
        print(json.dumps(entries, indent=2))
        return 0
    print(f"{'id':34} {'class':7} {'split':5} {'free m²':>8}  {'cells':>11}  kind")
    for e in sorted(entries, key=lambda e: (("small", "medium", "large").index(e["size_class"]), e["free_area_m2"])):
        kind = "room group" if e.get("derived") else "building"
        print(
            f"{e['id']:34} {e['size_class']:7} {e['split']:5} {e['free_area_m2']:8.1f}  "
            f"{e['width']:>5}x{e['height']:<5}  {kind}"
        )
    print(
        f"{len(entries)} maps; split: train (training), val (choosing checkpoints), test (results only; "
        "--maps bundled:test); licenses and sources: `areasearch maps --json` or the package's maps/README.md"
    )
    return 0


def add_maps_parser(sub: Subparsers) -> argparse.ArgumentParser:
    maps = sub.add_parser("maps", help="list the bundled maps with size class, split and free area")
    maps.add_argument("--size", nargs="+", choices=("small", "medium", "large"), help="only these size classes")
    maps.add_argument(
        "--split",
        nargs="+",
        choices=("train", "val", "test"),
        help="only these splits (train: trained on; val: checkpoints chosen on; test: reported on, never trained on)",
    )
    maps.add_argument("--json", action="store_true", help="print the full index entries (and split) as JSON")
    maps.set_defaults(func=cmd_maps)
    return maps


# ---------------------------------------------------------------------------------- eval


def cmd_eval(args: argparse.Namespace) -> int:
    """Evaluate goal planners (resumable); write episodes.csv, curves.jsonl, summaries and curves.png."""
    from .harness.evaluate import evaluate

    check_folder_path(Path(args.out).expanduser(), "output path")
    settings = _world_settings(args.set, EPISODE_OPTIONS, args.protocol)
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
        progress=sys.stderr,
        backend=args.backend,
        address=args.address,
        settings=settings,
        policies=_policies(args.policy),
    )
    out = Path(args.out)
    print((out / "summary.md").read_text())
    print(f"results in {out}: episodes.csv, curves.jsonl, summary.md, summary.json, summary.tex, curves.png")
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
    _add_robots(ev, several=True)
    ev.add_argument(
        "--maps",
        nargs="+",
        default=["bundled"],
        metavar="MAP",
        help="'bundled' (all bundled maps), 'bundled:train', 'bundled:val' or 'bundled:test' (the maps of one "
        "split; results go on bundled:test, see 'areasearch maps --split test'), bundled map ids, map folders "
        "with index.json, PNGs in them, ROS .yaml (default bundled)",
    )
    ev.add_argument("--sizes", nargs="+", choices=("small", "medium", "large"), help="only these size classes")
    ev.add_argument(
        "--maps-per-size", type=_positive_int, metavar="N", help="N maps per size class, evenly spaced by id"
    )
    ev.add_argument("--episodes", type=_positive_int, default=5, help="episodes per (map, team size) (default 5)")
    ev.add_argument("--seed", type=_seed, default=0, help="run seed; episode seeds derive from it (default 0)")
    _add_max_steps(ev)
    ev.add_argument("--out", required=True, help="results folder (created; an existing one is resumed)")
    ev.add_argument(
        "--workers", type=_positive_int, default=1, help="worker processes, or CPUs of a local Ray (default 1)"
    )
    ev.add_argument(
        "--backend", choices=("local", "ray"), default="local", help="episodes in local processes or Ray tasks"
    )
    ev.add_argument("--address", default=None, help="with --backend ray: an existing Ray cluster (default: start one)")
    _add_protocol(ev)
    _add_set(ev, "targets.count=50", "a world setting of every episode (recorded in config.json)")
    ev.set_defaults(func=cmd_eval)
    return ev


# ---------------------------------------------------------------------------------- assign

ASSIGN_OPTIONS = {
    "world.num_robots": "--robots (the robots file)",
    "world.robot.radius_m": "--radius-m",
    "world.camera.max_range_m": "--sensor-range-m",
}


def cmd_assign(args: argparse.Namespace) -> int:
    """Goals for your robots on your own map: JSON in (robots, targets), JSON out (:mod:`areasearch.service.assign`)."""
    from .config import search_config
    from .harness.report import write_text
    from .planners import choose_planner
    from .service.assign import assign_goals, assignments_json, dropped_lines, dumps, read_robots, read_targets

    out = Path(args.out) if args.out else None
    if out is not None:
        _output_file(out, "assignment")
    settings = _world_settings(args.set, ASSIGN_OPTIONS)
    config = search_config(settings) if settings else None
    robots = read_robots(args.robots)
    target_ids, targets = read_targets(args.targets) if args.targets else ([], None)
    choice = choose_planner(args.method, args.weights)
    assignments = assign_goals(
        args.map,
        robots.poses,
        choice.planner,
        targets,
        robots.past_positions,
        robots.past_goals,
        resolution=args.resolution,
        origin=args.origin,
        config=config,
        radius_m=args.radius_m,
        sensor_range_m=args.sensor_range_m,
        seed=args.seed,
        robot_names=robots.ids,
    )
    text = dumps(assignments_json(assignments, robots.ids, target_ids, choice.method, choice.record()))
    for line in dropped_lines(assignments, target_ids):
        print(f"areasearch: warning: {line}", file=sys.stderr)
    if out is not None:
        write_text(out, text, "assignment")
    else:
        sys.stdout.write(text)
    return 0


def add_assign_parser(sub: Subparsers) -> argparse.ArgumentParser:
    asg = sub.add_parser(
        "assign",
        help="goals for your robots on your own (partial) map: robots JSON in, goals and paths JSON out",
        description="One long-term goal per robot from a goal planner, on an occupancy map as SLAM makes it "
        "(unknown cells unexplored), with the planned path; poses and goals in metres in the map frame.",
    )
    asg.add_argument("--map", required=True, help="ROS map_server .yaml, or a .png/.pgm map with --resolution")
    asg.add_argument(
        "--robots",
        required=True,
        help='robots JSON: {"robots": [{"id", "x", "y", "yaw"}, ...]}, or - for standard input',
    )
    asg.add_argument("--targets", help='known targets JSON: {"targets": [{"id", "x", "y"}, ...]}')
    asg.add_argument("--method", help=METHOD_HELP)
    asg.add_argument("--weights", metavar="PREFIX", help=WEIGHTS_HELP)
    asg.add_argument("--resolution", type=_resolution, help="metres per cell of a .png/.pgm map")
    asg.add_argument(
        "--origin", type=_origin, nargs=2, metavar=("X", "Y"), help="map-frame x y of the image's lower-left corner"
    )
    asg.add_argument("--radius-m", type=_radius, help="robot footprint radius, metres (default 0.18)")
    asg.add_argument(
        "--sensor-range-m", type=_sensor_range, help="sensor range for information gain, metres (default 3.2)"
    )
    asg.add_argument("--seed", type=_seed, default=0, help="seed of the planner's random draws (default 0)")
    asg.add_argument("--out", help="write the JSON to this file (atomically) instead of stdout")
    _add_set(asg, "candidates.cluster_m=2.0")
    asg.set_defaults(func=cmd_assign)
    return asg


# ---------------------------------------------------------------------------------- serve


def cmd_serve(args: argparse.Namespace) -> int:
    """The goal service: ``areasearch assign`` over HTTP, warm, for robot stacks (:mod:`areasearch.service.serve`)."""
    from .service.serve import config_from_args, serve

    config = config_from_args(
        host=args.host,
        port=args.port,
        method=args.method,
        weights=args.weights,
        workers=args.workers,
        token=args.token,
        time_limit_s=args.time_limit_s,
        max_body_bytes=args.max_body_bytes,
        max_map_cells=args.max_map_cells,
        max_maps=args.max_maps,
        max_connections=args.max_connections,
        idle_timeout_s=args.idle_timeout_s,
        header_timeout_s=args.header_timeout_s,
    )
    return serve(config)


def add_serve_parser(sub: Subparsers) -> argparse.ArgumentParser:
    sv = sub.add_parser(
        "serve",
        help="HTTP JSON goal service for robot stacks: POST /assign with an OccupancyGrid and poses",
        description="A long-running service that answers what 'areasearch assign' answers, without its start-up: "
        "POST /assign, PUT /maps/{name}, GET /health, GET /methods, /docs. Binds 127.0.0.1 by default.",
    )
    sv.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)")
    sv.add_argument("--port", type=_non_negative_int, default=8000, help="TCP port, 0: a free one (default 8000)")
    sv.add_argument(
        "--method", help="planner of requests naming none (default greedy; 'areasearch methods' lists them)"
    )
    sv.add_argument("--weights", metavar="PREFIX", help=WEIGHTS_HELP + " (read at start-up)")
    sv.add_argument(
        "--workers", type=_positive_int, default=1, help="worker processes planning in parallel (default 1)"
    )
    sv.add_argument(
        "--token", help="require 'Authorization: Bearer TOKEN' (all but /health); or AREASEARCH_SERVE_TOKEN"
    )
    sv.add_argument("--time-limit-s", type=float, default=None, metavar="S", help="per request (default 30)")
    sv.add_argument(
        "--max-body-bytes", type=_positive_int, default=None, metavar="B", help="largest body (default 64 MiB)"
    )
    sv.add_argument(
        "--max-map-cells", type=_positive_int, default=None, metavar="C", help="largest map (default 25,000,000)"
    )
    sv.add_argument("--max-maps", type=_positive_int, default=None, metavar="N", help="stored maps (default 16)")
    sv.add_argument(
        "--max-connections", type=_positive_int, default=None, metavar="N", help="open connections (default 64)"
    )
    sv.add_argument(
        "--idle-timeout-s", type=float, default=None, metavar="S", help="close a connection idle this long (default 30)"
    )
    sv.add_argument(
        "--header-timeout-s", type=float, default=None, metavar="S", help="most for a request's head (default 10)"
    )
    sv.set_defaults(func=cmd_serve)
    return sv


# ---------------------------------------------------------------------------------- render


def cmd_render(args: argparse.Namespace) -> int:
    """One goal-planner episode as an animation plus its last frame; metrics as JSON."""
    from .harness.animate import compare_episodes, render_episode

    if args.method is None and not args.methods and args.weights is None:
        raise ConfigError("name the planner: --method NAME, --methods NAME NAME..., or --weights PREFIX")
    settings = _world_settings(args.set, EPISODE_OPTIONS, args.protocol)
    options = {
        "max_steps": args.max_steps,
        "every": args.every,
        "fps": args.fps,
        "settings": settings,
        "weights": args.weights,
        "progress": sys.stderr,
    }
    if args.methods:
        result = compare_episodes(args.methods, args.map, args.robots, args.seed, args.out, **options)
        print(result.pop("table"))
        _print_json(result)
        return 0
    summary = render_episode(args.method, args.map, args.robots, args.seed, args.out, **options)
    _print_json(summary)
    return 0


def add_render_parser(sub: Subparsers) -> argparse.ArgumentParser:
    rd = sub.add_parser("render", help="animate one goal-planner episode (GIF, or MP4 with ffmpeg); print metrics")
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
    _add_robots(rd)
    rd.add_argument("--seed", type=_seed, default=0, help="episode seed (an episodes.csv seed replays that episode)")
    _add_max_steps(rd)
    rd.add_argument("--every", type=_positive_int, default=40, help="a frame every K primitive steps (default 40)")
    rd.add_argument(
        "--fps",
        type=_fps,
        default=8.0,
        help=f"frames per second of the animation, {FPS_RANGE[0]:g}-{FPS_RANGE[1]:g} (default 8)",
    )
    rd.add_argument("--out", default="episode.gif", help="animation .gif or .mp4; last frame beside it as .png")
    _add_protocol(rd)
    _add_set(rd, "targets.count=50")
    rd.set_defaults(func=cmd_render)
    return rd


# ---------------------------------------------------------------------------------- train


def cmd_train(args: argparse.Namespace) -> int:
    """PPO training of a DA-HGNN / NCM policy (resumable); see :mod:`areasearch.training.train`."""
    from .training.train import load_config, summary_line, train

    out = Path(args.out).expanduser()
    check_folder_path(out, "run folder path")
    if args.config is None:
        if not args.resume:
            raise ConfigError("--config is required to start a run (--resume continues the run in --out with its own)")
        if not os.path.lexists(out / "config.json"):
            raise ConfigError(f"{out}: no run to resume (no config.json); give --config to start one")
    config = load_config(args.config or out / "config.json", parse_settings(args.set or ()))
    result = train(
        config,
        out,
        resume=args.resume,
        device=args.device,
        workers=args.workers,
        backend=args.backend,
        address=args.address,
        progress=sys.stderr,
        iterations=args.iterations,
    )
    print(summary_line(args.out, result, config))
    return 0


def add_train_parser(sub: Subparsers) -> argparse.ArgumentParser:
    tr = sub.add_parser(
        "train",
        help="train a DA-HGNN / NCM goal planner with PPO (resumable); writes checkpoints, logs and the policy",
        description="Re-running with --resume continues a killed run from its last checkpoint, with the config "
        "the run recorded (its config.json; a --config or --set that differs from it is refused, naming the "
        "settings); without --resume an existing run folder is never overwritten. policy.* always holds a "
        "policy to use: the last weights until a validation has run (policy.json says which).",
    )
    tr.add_argument(
        "--config",
        default=None,
        help="training config, TOML (configs/*.toml) or a run's config.json; needed to start a run, "
        "with --resume the run's own by default",
    )
    tr.add_argument("--out", required=True, help="run folder, e.g. runs/dahgnn")
    tr.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    tr.add_argument("--device", choices=("cpu", "cuda"), default="cpu", help="device of the learner (default cpu)")
    tr.add_argument(
        "--workers",
        type=_non_negative_int,
        default=None,
        help="rollout worker processes, 0: in this process (default: one per core)",
    )
    tr.add_argument("--backend", choices=("local", "ray"), default="local", help="rollout workers (default local)")
    tr.add_argument("--address", default=None, help="with --backend ray: address of an existing Ray cluster")
    tr.add_argument(
        "--iterations",
        type=_positive_int,
        default=None,
        metavar="N",
        help="stop once the run has N iterations in total, counted from its start (re-running the same "
        "command after a kill finishes the same run; a larger N extends it); the run ends at its "
        "total_decisions in any case",
    )
    _add_set(tr, "ppo.epochs=2 --set rollout.robots=[3]", "a training-config setting")
    tr.set_defaults(func=cmd_train)
    return tr


# ---------------------------------------------------------------------------------- methods


def cmd_methods(args: argparse.Namespace) -> int:
    """List every goal planner with its origin; plug-ins are imported and built once to check them."""
    from .planners import describe_planners

    rows = describe_planners()
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print(f"{'name':20} {'origin':34} description")
    for row in rows:
        origin = row["origin"] + ("" if row["status"] == "ok" else f" ({row['status']})")
        print(f"{row['name']:20} {origin:34} {row.get('description', '')}".rstrip())
        if "weights_sha256" in row:
            print(f"{'':20}   weights sha256 {row['weights_sha256']}")
        if "error" in row:
            print(f"{'':20}   {' '.join(str(row['error']).split())}")
    usable = sum(1 for row in rows if row["status"] == "ok")
    print(f"{usable} planners usable as --method; all fields: areasearch methods --json")
    return 0


def add_methods_parser(sub: Subparsers) -> argparse.ArgumentParser:
    mt = sub.add_parser(
        "methods",
        help="list the goal planners with their origin: built in, shipped policy, plug-in",
        description="Every planner --method takes: the built-in classical ones, the shipped learned policies "
        "(with their weights' SHA-256), the untrained networks, and plug-ins of other installed distributions "
        "(entry-point group areasearch.planners; each is imported and built once here, a broken one listed "
        "with its error).",
    )
    mt.add_argument("--json", action="store_true", help="print every field as JSON")
    mt.set_defaults(func=cmd_methods)
    return mt


# ---------------------------------------------------------------------------------- main


def build_parser() -> Parser:
    parser = Parser(
        prog="areasearch", description="Multi-robot collaborative area search (explore and cover), after DA-HGNN."
    )
    parser.add_argument("--version", action="version", version=f"areasearch {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_parser in (add_run_parser, add_maps_parser, add_eval_parser, add_render_parser, add_assign_parser):
        add_parser(sub)
    add_train_parser(sub)
    add_serve_parser(sub)
    add_methods_parser(sub)
    parser.commands = dict(sub.choices)
    return parser


def _error_line(message: object) -> str:
    """The one ``areasearch: error: ...`` line of a message: on one line, a word longer than 300
    characters (a path or value the user gave, perhaps a megabyte long) cut in its middle, the whole at
    most about 1,500 characters (:func:`areasearch.inputs.clip_words`)."""
    return f"areasearch: error: {clip_words(str(message))}"


def main(argv: Sequence[str] | None = None) -> int:
    """The command line: one subcommand with its arguments; its exit status. Bad input ends in one
    ``areasearch: error: ...`` line and status 2: an AreaSearchError, an integer beyond Python's
    conversion limit wherever it was met, a file that cannot be written (file too large, disk full,
    read-only file system: an OSError with a file name); never a traceback."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except AreaSearchError as exc:
        print(_error_line(exc), file=sys.stderr)
        return 2
    except ValueError as exc:
        if not is_int_digits_error(exc):
            raise
        print(_error_line(f"a value given is {int_digits_message()}"), file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. `areasearch maps | head` (before OSError: it is one)
        sys.stdout = open(os.devnull, "w")
        return 1
    except OSError as exc:
        if exc.filename is None or exc.errno not in WRITE_ERRORS:
            raise
        print(_error_line(f"{exc.filename}: {WRITE_ERRORS[exc.errno]}"), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("areasearch: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
