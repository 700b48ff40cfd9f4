"""The commands that do not play an evaluation episode: ``maps`` (the bundled maps), ``assign`` (goals
for your own robots, :mod:`areasearch.service.assign`), ``serve`` (the same as an HTTP service,
:mod:`areasearch.service.serve`), ``train`` (PPO, :mod:`areasearch.training.train`) and ``methods``
(every goal planner with its origin)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from ..config import REALISM_KEY, parse_settings
from ..errors import ConfigError
from ..folderlock import check_folder_path
from ..ros2.settings import MAX_PERIOD_S, MAX_TOLERANCE_M, MIN_PERIOD_S, POSE_SOURCES
from ..sim.scene import SIZE_CLASSES, bundled_index
from .options import (
    METHOD_HELP,
    WEIGHTS_HELP,
    Subparsers,
    add_realism,
    add_set,
    non_negative_int,
    origin_type,
    output_file,
    positive_int,
    radius_type,
    real_type,
    resolution_type,
    seed_type,
    sensor_range_type,
    world_options,
)

# ---------------------------------------------------------------------------------- maps


def cmd_maps(args: argparse.Namespace) -> int:
    """List the bundled maps: id, size class, split, free area, derived or whole building, license."""
    from ..sim.splits import SPLITS, split_maps

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
    for e in sorted(entries, key=lambda e: (SIZE_CLASSES.index(e["size_class"]), e["free_area_m2"])):
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
    maps.add_argument("--size", nargs="+", choices=SIZE_CLASSES, help="only these size classes")
    maps.add_argument(
        "--split",
        nargs="+",
        choices=("train", "val", "test"),
        help="only these splits (train: trained on; val: checkpoints chosen on; test: reported on, never trained on)",
    )
    maps.add_argument("--json", action="store_true", help="print the full index entries (and split) as JSON")
    maps.set_defaults(func=cmd_maps)
    return maps


# ---------------------------------------------------------------------------------- assign

ASSIGN_OPTIONS = {
    "world.num_robots": "--robots (the robots file)",
    "world.robot.radius_m": "--radius-m",
    "world.camera.max_range_m": "--sensor-range-m",
}


def cmd_assign(args: argparse.Namespace) -> int:
    """Goals for your robots on your own map: JSON in (robots, targets), JSON out (:mod:`areasearch.service.assign`)."""
    from ..harness.report import write_text
    from ..planners import choose_planner
    from ..service.assign import assign_goals, assignments_json, dropped_lines, dumps, read_robots, read_targets

    out = Path(args.out) if args.out else None
    if out is not None:
        output_file(out, "assignment")
    world = world_options(args.set, ASSIGN_OPTIONS)
    config = world.config() if world.given else None
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
    asg.add_argument("--resolution", type=resolution_type, help="metres per cell of a .png/.pgm map")
    asg.add_argument(
        "--origin", type=origin_type, nargs=2, metavar=("X", "Y"), help="map-frame x y of the image's lower-left corner"
    )
    asg.add_argument("--radius-m", type=radius_type, help="robot footprint radius, metres (default 0.18)")
    asg.add_argument(
        "--sensor-range-m", type=sensor_range_type, help="sensor range for information gain, metres (default 3.2)"
    )
    asg.add_argument("--seed", type=seed_type, default=0, help="seed of the planner's random draws (default 0)")
    asg.add_argument("--out", help="write the JSON to this file (atomically) instead of stdout")
    add_set(asg, "candidates.cluster_m=2.0")
    asg.set_defaults(func=cmd_assign)
    return asg


# ---------------------------------------------------------------------------------- serve


def cmd_serve(args: argparse.Namespace) -> int:
    """The goal service: ``areasearch assign`` over HTTP, warm, for robot stacks (:mod:`areasearch.service.serve`)."""
    from ..service.serve import config_from_args, serve

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
        settings=tuple(sorted(world_options(args.set, ASSIGN_OPTIONS).settings.items())) or None,
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
    sv.add_argument("--port", type=non_negative_int, default=8000, help="TCP port, 0: a free one (default 8000)")
    sv.add_argument(
        "--method", help="planner of requests naming none (default greedy; 'areasearch methods' lists them)"
    )
    sv.add_argument("--weights", metavar="PREFIX", help=WEIGHTS_HELP + " (read at start-up)")
    sv.add_argument("--workers", type=positive_int, default=1, help="worker processes planning in parallel (default 1)")
    sv.add_argument(
        "--token", help="require 'Authorization: Bearer TOKEN' (all but /health); or AREASEARCH_SERVE_TOKEN"
    )
    sv.add_argument("--time-limit-s", type=float, default=None, metavar="S", help="per request (default 30)")
    sv.add_argument(
        "--max-body-bytes", type=positive_int, default=None, metavar="B", help="largest body (default 64 MiB)"
    )
    sv.add_argument(
        "--max-map-cells", type=positive_int, default=None, metavar="C", help="largest map (default 25,000,000)"
    )
    sv.add_argument("--max-maps", type=positive_int, default=None, metavar="N", help="stored maps (default 16)")
    sv.add_argument(
        "--max-connections", type=positive_int, default=None, metavar="N", help="open connections (default 64)"
    )
    sv.add_argument(
        "--idle-timeout-s", type=float, default=None, metavar="S", help="close a connection idle this long (default 30)"
    )
    sv.add_argument(
        "--header-timeout-s", type=float, default=None, metavar="S", help="most for a request's head (default 10)"
    )
    add_set(sv, "candidates.distance_cell_m=0.1", "a decision setting of every request")
    sv.set_defaults(func=cmd_serve)
    return sv


# ---------------------------------------------------------------------------------- ros2

ROS2_OPTIONS = {
    "robots": "robots",
    "pose_source": "pose_source",
    "method": "method",
    "weights": "weights",
    "period_s": "period_s",
    "goal_tolerance_m": "goal_tolerance_m",
    "seed": "seed",
    "radius_m": "radius_m",
    "sensor_range_m": "sensor_range_m",
}
"""The options of ``areasearch ros2`` (argparse dest -> the node's ROS parameter they set)."""


def cmd_ros2(args: argparse.Namespace) -> int:
    """The ROS 2 node of a robot team, until Ctrl-C (:mod:`areasearch.ros2.node`); one error line
    without the ``ros2`` extra."""
    from ..ros2 import require_ros2

    require_ros2()
    from ..ros2.node import run

    given = {param: getattr(args, dest) for dest, param in ROS2_OPTIONS.items() if getattr(args, dest) is not None}
    return run(given, args.ros_args or [])


def add_ros2_parser(sub: Subparsers) -> argparse.ArgumentParser:
    r2 = sub.add_parser(
        "ros2",
        help="ROS 2 node for a robot team: /map and poses in, a goal per robot on /<ns>/goal_pose (Nav2) out",
        description="One node plans the goals of a whole team: it subscribes to /map, each robot's "
        "/<ns>/amcl_pose (or /<ns>/odom) and /areasearch/targets, and publishes each goal on /<ns>/goal_pose, "
        "markers on /areasearch/markers and the answer of 'areasearch assign' on /areasearch/status, every "
        "decision period and as soon as a robot reaches its goal. Needs the ros2 extra: "
        "pip install 'areasearch[ros2]'. Every option is also a ROS parameter (--ros-args -p period_s:=2.0). "
        "Runs until Ctrl-C.",
    )
    r2.add_argument("--robots", nargs="+", metavar="NS", help="the robots' namespaces, 1-8 (parameter robots)")
    r2.add_argument(
        "--pose-source",
        choices=POSE_SOURCES,
        help="amcl: /<ns>/amcl_pose (Nav2's AMCL), odom: /<ns>/odom (default amcl)",
    )
    r2.add_argument("--method", help=METHOD_HELP)
    r2.add_argument("--weights", metavar="PREFIX", help=WEIGHTS_HELP)
    r2.add_argument(
        "--period-s",
        type=real_type(MIN_PERIOD_S, MAX_PERIOD_S, "seconds"),
        metavar="S",
        help="seconds between decisions (default 5); a robot that reaches its goal triggers one at once",
    )
    r2.add_argument(
        "--goal-tolerance-m",
        type=real_type(0.0, MAX_TOLERANCE_M, "metres", low_open=True),
        metavar="M",
        help="a robot this near its goal has reached it (default 0.25, Nav2's xy_goal_tolerance)",
    )
    r2.add_argument("--seed", type=seed_type, help="seed of the planner's random draws (default 0)")
    r2.add_argument("--radius-m", type=radius_type, help="robot footprint radius, metres (default 0.18)")
    r2.add_argument(
        "--sensor-range-m", type=sensor_range_type, help="sensor range for information gain, metres (default 3.2)"
    )
    r2.add_argument(
        "--ros-args",
        nargs=argparse.REMAINDER,
        metavar="ARG",
        help="everything after it goes to ROS: -p NAME:=VALUE, -r FROM:=TO, --params-file FILE, --log-level LEVEL",
    )
    r2.set_defaults(func=cmd_ros2)
    return r2


# ---------------------------------------------------------------------------------- train


def cmd_train(args: argparse.Namespace) -> int:
    """PPO training of a DA-HGNN / NCM policy (resumable); see :mod:`areasearch.training.train`."""
    from ..training.train import load_config, summary_line, train

    out = Path(args.out).expanduser()
    check_folder_path(out, "run folder path")
    if args.config is None:
        if not args.resume:
            raise ConfigError("--config is required to start a run (--resume continues the run in --out with its own)")
        if not os.path.lexists(out / "config.json"):
            raise ConfigError(f"{out}: no run to resume (no config.json); give --config to start one")
    config = load_config(args.config or out / "config.json", _train_settings(args.set, args.realism))
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


def _train_settings(pairs: list[str] | None, realism: str | None) -> dict[str, Any]:
    """The training-config settings of ``--set`` and ``--realism``: the preset as the setting
    ``rollout.env.realism`` (the episodes' environment applies it under the other ``rollout.env`` settings),
    so that the run's ``config.json`` records it and a resume under another preset is refused, naming it."""
    settings = parse_settings(pairs or ())
    if realism is not None:
        if f"rollout.env.{REALISM_KEY}" in settings:
            raise ConfigError(f"give the preset once: --realism or --set rollout.env.{REALISM_KEY}=..., not both")
        settings[f"rollout.env.{REALISM_KEY}"] = realism
    return settings


def add_train_parser(sub: Subparsers) -> argparse.ArgumentParser:
    tr = sub.add_parser(
        "train",
        help="train a DA-HGNN / NCM goal planner with PPO (resumable); writes checkpoints, logs and the policy",
        description="Re-running with --resume continues a killed run from its last checkpoint, with the config "
        "the run recorded (its config.json; a --config, --set or --realism that differs from it is refused, "
        "naming the settings); without --resume an existing run folder is never overwritten. policy.* always holds a "
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
        type=non_negative_int,
        default=None,
        help="rollout worker processes, 0: in this process (default: one per core)",
    )
    tr.add_argument("--backend", choices=("local", "ray"), default="local", help="rollout workers (default local)")
    tr.add_argument("--address", default=None, help="with --backend ray: address of an existing Ray cluster")
    tr.add_argument(
        "--iterations",
        type=positive_int,
        default=None,
        metavar="N",
        help="stop once the run has N iterations in total, counted from its start (re-running the same "
        "command after a kill finishes the same run; a larger N extends it); the run ends at its "
        "total_decisions in any case",
    )
    add_realism(tr)
    add_set(tr, "ppo.epochs=2 --set rollout.robots=[3]", "a training-config setting")
    tr.set_defaults(func=cmd_train)
    return tr


# ---------------------------------------------------------------------------------- methods


def cmd_methods(args: argparse.Namespace) -> int:
    """List every goal planner with its origin; plug-ins are imported and built once to check them."""
    from ..planners import describe_planners

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
