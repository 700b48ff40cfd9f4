"""The bad-input corpus (``tests/bad_inputs/``, written by its ``make_corpus.py``) run through every
command of the CLI: each case must end with one ``areasearch: error: ...`` line naming what is wrong,
a non-zero exit, no traceback, and must leave every file of the working folder as it was (existing
outputs, the inputs, no stray temporary file).

A case is a command's good arguments (:data:`GOOD`) with one option changed: ``Case(command,
{option: value}, expected text)``. A new command joins by adding its good arguments to :data:`GOOD`
and its rows to :data:`CASES`; a new bad input by adding a file to the corpus and a row. Placeholders:
``{in}`` the corpus, ``{ws}`` the working folder (with the existing outputs), ``{ckpt}`` the
checkpoints the fixture writes, ``{gen}`` the inputs written at test time (bombs small on disk but
large in their headers, a 10 MB YAML, 10,000 robots, a named pipe, a symbolic link loop:
``make_corpus.write_generated``). Cases run ``areasearch.cli.main`` in this process (an exception
escaping it is the traceback a user would see); a few run it as a subprocess, as a user would, and
there the time and the peak memory are bounded too (:data:`MAX_SECONDS`, :data:`MAX_RSS_BYTES`).

Bounds: every in-process case ends within :data:`MAX_SECONDS` (a loaded 2-core machine; a case
takes about a second), and its error line is at most :data:`MAX_LINE` characters long (no unbounded
``repr`` of user input).
"""

from __future__ import annotations

import errno
import importlib.util
import json
import os
import re
import resource
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from areasearch.cli import main

CliRunner = Callable[..., subprocess.CompletedProcess[str]]

CORPUS = Path(__file__).resolve().parent / "bad_inputs"
MAX_SECONDS = 60.0
"""Most seconds one bad-input case may take (in this process or as a subprocess)."""
MAX_RSS_BYTES = 768 * 2**20
"""Most resident memory of a subprocess refusing a bad input (about 200 MB are Python, NumPy and
PIL; decoding the 20000 x 20000 bomb would take 400 MB more, expanding the YAML aliases gigabytes)."""
MAX_LINE = 600
"""Longest error line, characters, besides the paths of the working folder it names."""

GOOD: dict[str, list[str]] = {
    "run": ["run", "--map", "{in}/ros/good.yaml", "--robots", "2", "--max-steps", "5", "--out", "{ws}/existing.png"],
    "render": [
        "render", "--method", "greedy", "--map", "{in}/ros/good.yaml", "--robots", "2", "--max-steps", "5",
        "--every", "5", "--out", "{ws}/existing.gif",
    ],
    "eval": [
        "eval", "--methods", "greedy", "--maps", "{in}/ros/good.yaml", "--robots", "2", "--episodes", "1",
        "--max-steps", "5", "--out", "{ws}/results",
    ],
    "assign": [
        "assign", "--map", "{in}/ros/good.yaml", "--robots", "{in}/robots/good.json", "--out", "{ws}/goals.json",
    ],
    "maps": ["maps"],
    "train": ["train", "--config", "{in}/train/good.toml", "--out", "{ws}/run", "--workers", "0"],
}  # fmt: skip
"""Arguments with which each command succeeds (checked by :func:`test_the_good_arguments_work`)."""


@dataclass(frozen=True)
class Case:
    command: str
    changes: dict[str, str | list[str] | None]
    """Options to set (a list for several values) or, with None, to drop."""
    expect: str
    """Text the error line must contain."""
    argparse: bool = False
    """The error comes from argparse (a usage line precedes it)."""
    name: str = field(default="")
    extra: tuple[str, ...] = ()
    """Arguments appended as they are (an option given twice)."""

    def argv(self, places: dict[str, str]) -> list[str]:
        args = list(GOOD[self.command])
        for option, value in self.changes.items():
            if option in args:
                i = args.index(option)
                end = i + 1
                while end < len(args) and not args[end].startswith("--"):
                    end += 1
                del args[i:end]
            if value is not None:
                args += [option, *([value] if isinstance(value, str) else value)]
        return [a.format(**places) for a in [*args, *self.extra]]


MAP_OPTION = {"run": "--map", "render": "--map", "eval": "--maps", "assign": "--map"}
BROKEN_MAPS = [
    ("truncated_png", "{in}/maps/truncated.png", "not a readable image"),
    ("wrong_mode_png", "{in}/maps/wrong_mode.png", "mode"),
    ("png_no_free_cell", "{in}/maps/no_free.png", "no free cell"),
    ("yaml_missing_key", "{in}/ros/missing_key.yaml", "missing required field(s) free_thresh"),
    ("yaml_wrong_type", "{in}/ros/wrong_type.yaml", "field 'resolution' must be a number"),
    ("yaml_wrong_origin", "{in}/ros/wrong_origin.yaml", "field 'origin' must be a list of three numbers"),
    ("yaml_image_missing", "{in}/ros/missing_image.yaml", "no_such_image.pgm: map image not found"),
    ("yaml_image_truncated", "{in}/ros/truncated_image.yaml", "not a readable image"),
    ("yaml_no_free_cell", "{in}/ros/no_free.yaml", "no free cell"),
    ("yaml_syntax", "{in}/ros/not_yaml.yaml", "not valid YAML"),
    ("map_missing", "{in}/nowhere/lost.yaml", "lost.yaml"),
    # lossy images, YAML bombs and odd values, decompression bombs, not-a-file paths
    ("yaml_jpeg_image", "{in}/ros/jpeg.yaml", "a JPEG image by its content, though its name ends in .png"),
    ("yaml_aliases", "{in}/ros/aliases.yaml", "anchors and aliases (&name, *name) are not allowed (line 1)"),
    ("yaml_non_scalar", "{in}/ros/non_scalar.yaml", "field 'resolution' must be a number of metres per cell"),
    ("yaml_far_origin", "{in}/ros/far_origin.yaml", "field 'origin' (1e+300, 0) lies farther than 1e+07 m"),
    ("yaml_fine_resolution", "{in}/ros/fine_resolution.yaml", "must be in [0.001, 10.0] metres per cell, got 1e-300"),
    ("yaml_large", "{gen}/big.yaml", "big.yaml: map YAML is larger than 65,536 bytes, the limit"),
    ("png_bomb", "{gen}/bomb.yaml", "bomb.png: the image declares 400,000,000 pixels, more than the limit"),
    ("png_bomb_6k", "{gen}/bomb6k.yaml", "bomb6k.png: the image declares 6000 x 6000 pixels, more than the limit"),
    ("pgm_header_lies", "{gen}/lying.yaml", "lying.pgm: the image declares 900,000,000 pixels"),
    ("yaml_fifo", "{gen}/fifo.yaml", "fifo.yaml: map YAML is a named pipe (FIFO), not a regular file"),
    ("yaml_symlink_loop", "{gen}/loop.yaml", "loop.yaml: map YAML is a symbolic link loop"),
]


def _map_cases() -> list[Case]:
    cases = []
    for command, option in MAP_OPTION.items():
        for name, path, expect in BROKEN_MAPS:
            if command == "assign" and name == "wrong_mode_png":
                continue  # assign reads a 16-bit PNG (by its full range); a map folder's PNG must be 8-bit
            changes: dict[str, str | list[str] | None] = {option: path}
            if command == "assign" and path.endswith(".png"):
                changes["--resolution"] = "0.05"
            cases.append(Case(command, changes, expect, name=name))
        small = "smaller than the robots" if command == "assign" else "no room for a robot"
        for name, path in (("png_free_space_too_small", "{in}/maps/tiny_free.png"),
                           ("yaml_free_space_too_small", "{in}/ros/tiny_free.yaml")):  # fmt: skip
            changes = {option: path}
            if command == "assign":
                changes["--robots"] = "{in}/robots/in_tiny.json"
                if path.endswith(".png"):
                    changes["--resolution"] = "0.05"
            cases.append(Case(command, changes, small, name=name))
    return cases


CASES: list[Case] = [
    *_map_cases(),
    # unknown method
    Case("run", {"--method": "teleport"}, "unknown planner 'teleport'"),
    Case("render", {"--method": "teleport"}, "unknown planner 'teleport'"),
    Case("eval", {"--methods": ["greedy", "teleport"]}, "unknown method(s) teleport"),
    Case("assign", {"--method": "teleport"}, "unknown planner 'teleport'"),
    # negative or zero counts (one argparse type per kind of option, the same on every command)
    Case("run", {"--robots": "0"}, "--robots", argparse=True),
    Case("run", {"--robots": "-2"}, "--robots", argparse=True),
    Case("run", {"--robots": "9"}, "argument --robots: at most 8 robots, got 9", argparse=True),
    Case("run", {"--max-steps": "0"}, "argument --max-steps: expected a positive integer", argparse=True),
    Case("run", {"--seed": "-1"}, "argument --seed: expected a non-negative integer seed", argparse=True),
    Case("render", {"--robots": "0"}, "argument --robots: expected a positive integer, got 0", argparse=True),
    Case("render", {"--robots": "9"}, "argument --robots: at most 8 robots, got 9", argparse=True),
    Case("render", {"--every": "0"}, "argument --every: expected a positive integer", argparse=True),
    Case("render", {"--fps": "-1"}, "argument --fps: expected a number in [0.1, 100] (frames per second), got '-1'",
         argparse=True),
    Case("render", {"--max-steps": "0"}, "argument --max-steps: expected a positive integer", argparse=True),
    Case("eval", {"--robots": "0"}, "argument --robots: expected a positive integer, got 0", argparse=True),
    Case("eval", {"--robots": ["2", "9"]}, "argument --robots: at most 8 robots, got 9", argparse=True),
    Case("eval", {"--episodes": "0"}, "argument --episodes: expected a positive integer", argparse=True),
    Case("eval", {"--episodes": "-1"}, "argument --episodes: expected a positive integer", argparse=True),
    Case("eval", {"--workers": "0"}, "argument --workers: expected a positive integer", argparse=True),
    Case("eval", {"--max-steps": "-5"}, "argument --max-steps: expected a positive integer", argparse=True),
    Case("eval", {"--maps-per-size": "0"}, "argument --maps-per-size: expected a positive integer", argparse=True),
    Case("eval", {"--seed": "-1"}, "argument --seed: expected a non-negative integer seed", argparse=True),
    Case("eval", {"--seed": "x"}, "argument --seed: expected a non-negative integer seed, got 'x'", argparse=True),
    Case("assign", {"--radius-m": "0"}, "argument --radius-m: expected a number in (0, 5] (metres)", argparse=True),
    Case("assign", {"--radius-m": "-0.1"}, "argument --radius-m: expected a number in (0, 5]", argparse=True),
    Case("assign", {"--sensor-range-m": "-3"}, "argument --sensor-range-m: expected a number in (0, 1000]",
         argparse=True),
    Case("assign", {"--map": "{in}/ros/good.png", "--resolution": "0"}, "argument --resolution: expected a number in "
         "[0.001, 10] (metres per cell), got '0'", argparse=True),
    Case("assign", {"--map": "{in}/ros/good.png", "--resolution": "-0.05"}, "expected a number in [0.001, 10]",
         argparse=True),
    Case("assign", {"--map": "{in}/ros/good.png", "--resolution": "1e-300"}, "expected a number in [0.001, 10]",
         argparse=True),
    Case("assign", {"--map": "{in}/ros/good.png", "--resolution": "0.05", "--origin": ["1e300", "0"]},
         "argument --origin: expected a number in [-1e+07, 1e+07] (metres), got '1e300'", argparse=True),
    Case("assign", {"--map": "{in}/ros/jpeg_named.png", "--resolution": "0.05"}, "a JPEG image by its content"),
    Case("assign", {"--map": "{gen}/bomb.png", "--resolution": "0.05"}, "declares 400,000,000 pixels"),
    Case("assign", {"--map": "{gen}/lying.pgm", "--resolution": "0.05"}, "declares 900,000,000 pixels"),
    Case("assign", {"--map": "{in}/ros/good.png", "--resolution": "nan"}, "argument --resolution: expected a number",
         argparse=True),
    Case("assign", {"--map": "{in}/ros/good.png"}, "needs its resolution"),
    Case("assign", {"--robots": "{in}/robots/empty.json"}, "'robots' is empty"),
    Case("maps", {"--size": "huge"}, "invalid choice: 'huge'", argparse=True),
    # robots in walls or outside the map, NaN or infinite poses, malformed robots files
    Case("assign", {"--robots": "{in}/robots/in_wall.json"}, "robot 'b' at (0.02, 1.5) stands on an occupied cell"),
    Case("assign", {"--robots": "{in}/robots/outside.json"}, "robot 'b' at (7.5, 1.5) lies outside the map"),
    Case("assign", {"--robots": "{in}/robots/below_origin.json"}, "robot 'a' at (1, -0.4) lies outside the map"),
    Case("assign", {"--robots": "{in}/robots/nan.json"}, "robots[0].x must be a finite number, got nan"),
    Case("assign", {"--robots": "{in}/robots/infinite.json"}, "robots[0].y must be a finite number, got inf"),
    Case("assign", {"--robots": "{in}/robots/nan_yaw.json"}, "robots[0].yaw must be a finite number"),
    Case("assign", {"--robots": "{in}/robots/string_pose.json"}, "robots[0].x must be a number, got '1.0'"),
    Case("assign", {"--robots": "{in}/robots/overlap.json"}, "robot 'a' and robot 'b' overlap"),
    Case("assign", {"--robots": "{in}/robots/not_json.json"}, "not_json.json: not valid JSON"),
    Case("assign", {"--robots": "{in}/robots/missing.json"}, "missing.json: robots file not found"),
    Case("assign", {"--targets": "{in}/robots/targets_outside.json"}, "target 0 at (1, 9) lies outside the map"),
    Case("assign", {"--targets": "{in}/robots/targets_nan.json"}, "targets[0].x must be a finite number"),
    # extreme numbers, huge counts, overlapping footprints, unknown top-level keys
    Case("assign", {"--robots": "{in}/robots/far.json"}, "robot 'a' at (1e+20, 1) lies outside the map"),
    Case("assign", {"--targets": "{in}/robots/targets_far.json"}, "target 0 at (1, 1e+20) lies outside the map"),
    Case("assign", {"--robots": "{gen}/many_robots.json"}, "10000 robots; the planners plan for at most 8"),
    Case("assign", {"--robots": "{in}/robots/footprints_overlap.json"},
         "centres 0.200 m apart, less than the footprint diameter 0.36 m"),
    Case("assign", {"--robots": "{in}/robots/unknown_top_key.json"}, "unknown top-level field(s) 'robts'"),
    Case("assign", {"--targets": "{in}/robots/targets_unknown_top_key.json"}, "unknown top-level field(s) 'target'"),
    Case("assign", {"--robots": "{gen}/fifo.yaml"}, "robots file is a named pipe (FIFO), not a regular file"),
    Case("assign", {"--robots": "{gen}/loop.yaml"}, "robots file is a symbolic link loop"),
    # an option given twice
    Case("eval", {}, "argument --methods: given twice", argparse=True, name="methods-twice",
         extra=("--methods", "random")),
    Case("run", {}, "argument --robots: given twice", argparse=True, name="robots-twice", extra=("--robots", "3")),
    Case("assign", {}, "argument --map: given twice", argparse=True, name="map-twice", extra=("--map", "x.yaml")),
    Case("render", {}, "argument --out: given twice", argparse=True, name="out-twice", extra=("--out", "x.gif")),
    Case("train", {}, "argument --out: given twice", argparse=True, name="out-twice", extra=("--out", "{ws}/run2")),
    # output paths that cannot take the output
    Case("run", {"--out": "{ws}/results"}, "picture path is a folder"),
    Case("run", {"--out": "{ws}/no_such_folder/ep.png"}, "folder for the picture does not exist"),
    Case("render", {"--out": "{ws}/movie.gif"}, "animation path is a folder"),
    Case("render", {"--out": "{ws}/existing.png"}, "animation must be a .gif or .mp4 file"),
    Case("eval", {"--out": "{ws}/existing.png"}, "output path is an existing file; give a folder"),
    Case("eval", {"--out": "{ws}/other_run"}, "holds episodes of a run with other settings"),
    Case("assign", {"--out": "{ws}/results"}, "assignment path is a folder"),
    # an output path under a regular file: refused before any work
    Case("run", {"--out": "{ws}/existing.gif/ep.png"}, "existing.gif is a file, not a folder"),
    Case("render", {"--out": "{ws}/existing.png/sub/ep.gif"}, "existing.png is a file, not a folder"),
    Case("eval", {"--out": "{ws}/existing.png/sub"}, "cannot make the folder there: {ws}/existing.png is a file"),
    # episodes as MCAP: a path under a file, one episode only, selectors that select nothing
    Case("render", {"--out": "{ws}/existing.png/ep.mcap"}, "existing.png is a file, not a folder"),
    Case("render", {"--method": None, "--methods": ["greedy", "random"], "--out": "{ws}/ep.mcap"},
         "an .mcap file holds one episode: name one --method"),
    Case("render", {"--out": "{ws}/ep.mcap", "--belief": "team"}, "--belief draws a second panel"),
    Case("eval", {"--record-mcap": "method"}, "--record-mcap takes 'all' or KEY=VALUE"),
    Case("eval", {"--record-mcap": "colour=red"}, "--record-mcap: unknown key 'colour'"),
    Case("eval", {"--record-mcap": "robots=two"}, "--record-mcap: robots must be a non-negative integer"),
    Case("eval", {"--record-mcap": "method=random"}, "--record-mcap method=random matches no episode"),
    # --replace: a method with weights, listed in --methods
    Case("eval", {"--replace": "greedy"}, "--replace greedy: only a method with weights"),
    Case("eval", {"--replace": "ncm"}, "--replace ncm: add ncm to --methods to play it again"),
    Case("assign", {"--out": "{ws}/goals.json/sub.json"}, "goals.json is a file, not a folder"),
    Case("train", {"--out": "{ws}/existing.png/run"}, "cannot make the folder there: {ws}/existing.png is a file"),
    # checkpoints: a JSON that does not match its weights, a truncated safetensors file
    Case("assign", {"--method": "dahgnn-untrained", "--weights": "{ckpt}/mismatch"}, "do not match mismatch.json"),
    Case("assign", {"--method": "ncm-untrained", "--weights": "{ckpt}/truncated"}, "truncated.safetensors: cannot"),
    Case("assign", {"--method": "ncm-untrained", "--weights": "{ckpt}/absent"}, "absent.json: cannot read the policy"),
    Case("assign", {"--method": "greedy", "--weights": "{ckpt}/truncated"}, "planner 'greedy' takes no weights"),
    # training configs and run folders
    Case("train", {"--config": "{in}/train/missing.toml"}, "missing.toml: cannot read the training config"),
    Case("train", {"--config": "{in}/train/truncated.toml"}, "not valid TOML"),
    Case("train", {"--config": "{in}/train/wrong_type.toml"}, "ppo.epochs must be an integer"),
    Case("train", {"--config": "{in}/train/unknown_key.toml"}, "unknown setting ppo.epoch"),
    Case("train", {"--config": "{in}/train/zero_robots.toml"}, "rollout.robots must be an integer from 1 to 8, got 0"),
    Case("train", {"--config": "{in}/train/negative_count.toml"}, "total_decisions must be an integer from 1 to"),
    Case("train", {"--config": "{in}/train/test_maps.toml"}, "name a split (bundled:train)"),
    Case("train", {"--config": "{in}/train/unknown_map.toml"}, "no_such_map"),
    Case("train", {"--out": "{ws}/existing.png"}, "run folder path is an existing file; give a folder"),
    Case("train", {"--out": "{ws}/other_run"}, "a run is already there; pass --resume"),
    Case("train", {"--workers": "-1"}, "argument --workers: expected a non-negative integer", argparse=True),
    Case("train", {"--set": "ppo.learning_rate=-1"}, "ppo.learning_rate must be a positive number"),
    Case("train", {"--set": "ppo.learning_rate=nan"}, "--set 'ppo.learning_rate=nan': ppo.learning_rate must be"),
    Case("train", {"--set": "ppo.epoch=2"}, "unknown setting ppo.epoch"),
    Case("train", {"--set": "ppo.epochs"}, "--set 'ppo.epochs': expected KEY=VALUE"),
    # --set KEY=VALUE on the commands that build a world: one parser, the world's keys
    *[Case(command, {"--set": "robot.radius_m"}, "--set 'robot.radius_m': expected KEY=VALUE", name="set-no-value")
      for command in ("run", "render", "eval", "assign")],
    *[Case(command, {"--set": "robot.wheels=4"}, "unknown setting 'robot.wheels'; known settings: robot.radius_m",
           name="set-unknown-key") for command in ("run", "render", "eval", "assign")],
    *[Case(command, {"--set": "targets.count=inf"}, "--set 'targets.count=inf': targets.count must be a finite",
           name="set-infinite") for command in ("run", "render", "eval", "assign")],
    *[Case(command, {"--set": "robot=0.2"}, "setting 'robot' is a group of settings", name="set-group")
      for command in ("run", "render", "eval", "assign")],
    *[Case(command, {"--set": "targets.count=-1"}, "targets.count must be an integer >= 0", name="set-bad-value")
      for command in ("run", "render", "eval", "assign")],
    *[Case(command, {"--set": "robot.radius_m=1e9"}, "robot.radius_m must be a positive number of at most 5",
           name="set-huge-length") for command in ("run", "render", "eval")],
    *[Case(command, {"--set": "camera.max_range_m=1e300"}, "camera.max_range_m must be a positive number of at most",
           name="set-huge-range") for command in ("run", "render", "eval")],
    *[Case(command, {"--set": "camera.width_px=100000000"}, "camera.width_px must be an integer from 2 to 4,096",
           name="set-huge-count") for command in ("run", "render", "eval", "assign")],
    *[Case(command, {"--set": "num_robots=2"}, "--set num_robots=... is not allowed here; use --robots",
           name="set-num-robots") for command in ("run", "render", "eval", "assign")],
    *[Case(command, {"--set": "world.max_steps=5"}, "--set world.max_steps=... is not allowed here; use --max-steps",
           name="set-max-steps") for command in ("run", "render", "eval")],
    # the coverage protocol: an unknown name, a radius that contradicts it, named twice
    *[Case(command, {"--set": "protocol=papr"}, "protocol must be one of 'paper', 'passby', got 'papr'",
           name="set-unknown-protocol") for command in ("run", "render", "eval")],
    *[Case(command, {"--set": "targets.cover_radius_m=0.3"}, "targets.cover_radius_m=0.3 contradicts protocol 'paper'",
           name="set-radius-against-protocol") for command in ("run", "render", "eval")],
    *[Case(command, {"--protocol": "passby", "--set": "protocol=paper"}, "give the protocol once",
           name="protocol-twice") for command in ("run", "render", "eval")],
    # noise and detection: a negative noise, a probability above 1, an unknown detection model
    *[Case(command, {"--set": "noise.forward=-0.1"}, "noise.forward must be a number from 0 to 1, got -0.1",
           name="set-negative-noise") for command in ("run", "eval")],
    *[Case(command, {"--set": "detection.p_far=1.5"}, "detection.p_far must be a number from 0 to 1, got 1.5",
           name="set-bad-probability") for command in ("run", "eval")],
    *[Case(command, {"--set": "detection.model=sometimes"},
           "detection.model must be one of 'certain', 'constant', 'linear', got 'sometimes'",
           name="set-unknown-detection") for command in ("run", "eval")],
    Case("assign", {"--set": "robot.radius_m=0.2"}, "--set robot.radius_m=... is not allowed here; use --radius-m"),
    Case("assign", {"--set": "camera.max_range_m=4"}, "is not allowed here; use --sensor-range-m"),
    Case("train", {"--device": "tpu"}, "invalid choice: 'tpu'", argparse=True),
    # the Ray backend
    Case("eval", {"--address": "127.0.0.1:1"}, "--address is for --backend ray"),
    Case("eval", {"--backend": "ray", "--address": "127.0.0.1:1"}, "no Ray cluster reachable there"),
    Case("eval", {"--backend": "ray", "--address": "nowhere"}, "--address must be host:port"),
    # round three: output paths, sizes inside trusted files, big integers, NUL bytes, write errors, resume folders
    # output paths that are devices, named pipes or sockets: refused before any work, never replaced
    *[Case(command, {"--out": "/dev/null"}, f"/dev/null: {what} path is a character device, not a regular file",
           name="out-dev-null") for command, what in (("run", "picture"), ("assign", "assignment"))],
    *[Case(command, {"--out": "/dev/null"}, f"/dev/null: {what} is a character device; give a folder",
           name="out-dev-null") for command, what in (("eval", "output path"), ("train", "run folder path"))],
    Case("run", {"--out": "{gen}/outputs/fifo.png"}, "fifo.png: picture path is a named pipe (FIFO), not a regular "
         "file", name="out-fifo"),
    Case("render", {"--out": "{gen}/outputs/fifo.gif"}, "fifo.gif: animation path is a named pipe (FIFO)",
         name="out-fifo"),
    Case("render", {"--out": "{gen}/outputs/frame.gif"}, "frame.png: last frame path is a named pipe (FIFO)",
         name="out-frame-fifo"),
    Case("assign", {"--out": "{gen}/outputs/fifo.json"}, "fifo.json: assignment path is a named pipe (FIFO)",
         name="out-fifo"),
    *[Case(command, {"--out": "{gen}/outputs/fifo_dir"}, "fifo_dir: {what} is a named pipe (FIFO); give a folder"
           .replace("{what}", what), name="out-fifo") for command, what in (("eval", "output path"),
                                                                           ("train", "run folder path"))],
    # a path component over 255 bytes (an option, a map YAML's image), a NUL byte in a map YAML's image
    *[Case(command, {"--out": "{ws}/" + "x" * 300 + suffix}, f"has a component of {300 + len(suffix)} bytes; a file or "
           "folder name is at most 255 bytes", name="out-long-name")
      for command, suffix in (("run", ".png"), ("render", ".gif"), ("assign", ".json"), ("eval", ".out"),
                              ("train", ".out"))],
    *[Case(command, {option: "{in}/ros/" + "m" * 300 + ".yaml"}, "has a component of 305 bytes",
           name="map-long-name") for command, option in MAP_OPTION.items()],
    *[Case(command, {option: "{in}/ros/long_image.yaml"}, "long_image.yaml: field 'image' 'mmmm",
           name="yaml-image-long-name") for command, option in MAP_OPTION.items()],
    *[Case(command, {option: "{in}/ros/nul_image.yaml"}, "nul_image.yaml: field 'image' 'good\\x00.png' holds a NUL "
           "byte, which no path can", name="yaml-image-nul") for command, option in MAP_OPTION.items()],
    # sizes inside a policy file beside valid weights (fields that shape no tensor, a network too large)
    *[Case(command, {"--method": "ncm-untrained", "--weights": f"{{ckpt}}/{name}"}, expect, name=f"policy-{name}")
      for command in ("run", "render", "assign")
      for name, expect in (
          ("huge_sinkhorn", "huge_sinkhorn.json: network.sinkhorn_iters must be an integer from 1 to 1,000, "
                            "got 1000000000"),
          ("huge_neighbours", "network.graph.neighbours must be an integer from 1 to 256, got 1000000000"),
          ("huge_patch", "network.graph.patch_cells must be an integer from 0 to 256, got 1000000"),
          ("huge_network", "huge_network.json: the network has 61,484,949 parameters, more than the limit of "
                           "50,000,000"),
          ("huge_int", "huge_int.json: cannot read the policy config: not valid JSON: an integer longer than 4,300 "
                       "digits"),
      )],
    # world and decision settings that become array sizes, loop counts or cell counts: bounded
    *[Case(command, {"--set": setting}, expect, name=f"set-{setting.split('=')[0]}")
      for command in ("run", "render", "eval", "assign")
      for setting, expect in (
          ("decisions.map_cells=100000", "decisions.map_cells must be an integer from 1 to 2,048, got 100000"),
          ("paths.min_aim_m=1e308", "paths.min_aim_m must be a number from 0 to 100, got 1e+308"),
          ("paths.primitive_search_m=1e308", "paths.primitive_search_m must be a number from 0 to 100"),
          ("paths.path_buffer_cells=1000000000", "paths.path_buffer_cells must be an integer from 1 to 1,000,000"),
          ("paths.primitive_search_expansions=100000000000", "paths.primitive_search_expansions must be an integer "
                                                             "from 1 to 10,000,000"),
          ("candidates.min_frontier_cells=1000000000", "candidates.min_frontier_cells must be an integer from 1 to"),
          ("reward.time_per_step=1e308", "reward.time_per_step must be a number from -1e+06 to 1e+06"),
          ("robot.radius_m=" + "9" * 400, "setting 'robot.radius_m' must be a finite number"),
      ) if not (command == "assign" and setting.startswith("robot."))],
    # integers beyond Python's 4,300-digit conversion limit: in files, --set values and integer options
    *[Case(command, {option: "{in}/ros/huge_int.yaml"}, "huge_int.yaml: not valid YAML (an integer longer than "
           "4,300 digits", name="yaml-huge-int") for command, option in MAP_OPTION.items()],
    Case("assign", {"--robots": "{in}/robots/huge_int.json"}, "huge_int.json: not valid JSON: an integer longer than "
         "4,300 digits"),
    Case("assign", {"--targets": "{in}/robots/targets_huge_int.json"}, "targets_huge_int.json: not valid JSON: an "
         "integer longer than 4,300 digits"),
    *[Case(command, {"--set": "targets.count=" + "9" * 5000}, "targets.count is an integer longer than 4,300 digits",
           name="set-huge-int") for command in ("run", "render", "eval", "assign")],
    *[Case(command, {option: "9" * 5000}, f"argument {option}: expected {what}, got an integer longer than 4,300 "
           "digits", argparse=True, name=f"huge-int{option}")
      for command, option, what in (("run", "--seed", "a non-negative integer seed"),
                                    ("render", "--every", "a positive integer"),
                                    ("eval", "--episodes", "a positive integer"),
                                    ("train", "--workers", "a non-negative integer"))],
    # numeric options at their extremes: refused by the option's type, naming it
    *[Case("render", {"--fps": fps}, f"argument --fps: expected a number in [0.1, 100] (frames per second), got "
           f"'{fps}'", argparse=True, name=f"fps-{fps}") for fps in ("1e-9", "inf", "nan", "1e308")],
    *[Case("assign", {option: value}, f"argument {option}: expected a number in", argparse=True,
           name=f"{option.strip('-')}-{value}")
      for option in ("--resolution", "--radius-m", "--sensor-range-m") for value in ("inf", "1e308")],
    Case("assign", {"--map": "{in}/ros/good.png", "--resolution": "0.05", "--origin": ["inf", "0"]},
         "argument --origin: expected a number in [-1e+07, 1e+07] (metres), got 'inf'", argparse=True),
    # error lines quote user input cut to a bounded length (a 1 MB argument)
    Case("run", {"--method": "m" * 2**20}, "unknown planner 'mmmm", name="1mb-method"),
    Case("run", {"--map": "m" * 2**20}, "mmmm...", name="1mb-map"),
    Case("assign", {"--robots": "r" * 2**20}, "rrrr...", name="1mb-robots"),
    Case("eval", {"--set": "robot.radius_m=" + "x" * 2**20}, "robot.radius_m must be a finite number", name="1mb-set"),
    Case("render", {"--fps": "f" * 2**20}, "argument --fps: expected a number in [0.1, 100]", argparse=True,
         name="1mb-fps"),
    Case("maps", {"--size": "s" * 2**20}, "argument --size: invalid choice: 'ssss", argparse=True, name="1mb-choice"),
    # damaged results folders resumed by eval (make_corpus.write_results): one line naming the file and the row
    *[Case("eval", {"--out": f"{{gen}}/results/{folder}"}, expect,
           name=f"resume-{folder}")
      for folder, expect in (
          ("config_list", "config.json: the results config must be a JSON object, got list"),
          ("config_folder", "config.json: results config is a folder, not a regular file"),
          ("config_fifo", "config.json: results config is a named pipe (FIFO), not a regular file"),
          ("config_not_utf8", "config.json: not valid JSON: not UTF-8 text (byte 10)"),
          ("config_huge_int", "config.json: not valid JSON: an integer longer than 4,300 digits"),
          ("map_changed", "config.json: map good has changed since its episodes were played (SHA-256 "
                          "000000000000... recorded"),
          ("maps_malformed", "config.json: field 'maps' must map each map id to the SHA-256 of its content"),
          ("episodes_folder", "episodes.csv: episodes file is a folder, not a regular file"),
          ("episodes_fifo", "episodes.csv: episodes file is a named pipe (FIFO), not a regular file"),
          ("episodes_not_utf8", "episodes.csv: line 2: not UTF-8 text"),
          ("cover_250", "episodes.csv:2: impossible row: covered_pct = 250 is not a percentage from 0 to 100"),
          ("negative_time", "episodes.csv:2: impossible row: time_e = -5 is not a step from 0 to 10,000,000"),
          ("nan_cover", "episodes.csv:2: impossible row: covered_pct = nan is not a percentage"),
          ("infinite_length", "episodes.csv:2: impossible row: path_length_m = inf is not a finite number >= 0"),
          ("huge_int_row", "episodes.csv:2: malformed row (an integer longer than 4,300 digits"),
          ("curve_nan", "curves.jsonl:1: impossible curve: explored_pct must be percentages from 0 to 100"),
          ("curves_folder", "curves.jsonl: curve log is a folder, not a regular file"),
      )],
    # round three: training (--resume, checkpoints)
    # damaged run folders (make_corpus.write_runs): `train --out RUN --resume`, the run's own config
    *[Case("train", {"--config": None, "--out": f"{{gen}}/runs/{run}", "--resume": []}, expect, name=f"resume-{run}")
      for run, expect in (
          ("no_checkpoint", "no checkpoint.json, but the run's checkpoint-000001.safetensors, progress.csv are there; "
                            "nothing was changed"),
          ("no_config", "no_config: no run to resume (no config.json); give --config to start one"),
          ("lying_iteration", "checkpoint.json: iteration = 7, but progress.csv has rows up to iteration 1"),
          ("negative_count", "checkpoint.json: decisions must be an integer >= 0, got -4"),
          ("bool_count", "checkpoint.json: iteration must be an integer >= 0, got True"),
          ("bad_param_groups", "checkpoint.json: param_groups[0].eps = 0.5; the trainer's Adam has 1e-05"),
          ("weights_path", "checkpoint.json: weights must be 'checkpoint-000001.safetensors' (its iteration's file)"),
          ("wrong_shape", "checkpoint-000001.safetensors: tensor model/encoders.robot.0.weight is torch.float32 "
                          "[3, 3]; the run's network and optimizer need torch.float32 [4, 116]"),
          ("wrong_dtype", "tensor model/encoders.robot.0.weight is torch.float64 [4, 116]"),
          ("optimizer_shape", "tensor optim/0/exp_avg is torch.float32 [2, 2, 2]; the run's network and optimizer"),
          ("optimizer_unknown", "tensor 'optim/9999/exp_avg' is no part of the trainer's Adam state"),
          ("nan_weight", "tensor model/encoders.robot.0.weight holds NaN or infinite values"),
          ("checkpoint_fifo", "checkpoint.json: checkpoint is a named pipe (FIFO), not a regular file"),
          ("config_folder", "config.json: training config is a folder, not a regular file"),
          ("config_not_object", "config.json: a training config must be a table of settings, got list"),
          ("config_not_utf8", "config.json: cannot read the training config: not UTF-8 text (byte 10)"),
          ("config_huge_int", "config.json: not valid JSON: an integer longer than 4,300 digits"),
          ("progress_not_utf8", "progress.csv: cannot read the log: not UTF-8 text"),
          ("progress_columns", "progress.csv: its columns ('iteration,decisions,episodes') are not this run's"),
      )],
    *[Case("train", {"--out": "{gen}/runs/no_config", **resume}, "no_config: holds a training run's "
           "checkpoint-000001.safetensors, checkpoint.json, progress.csv but no config.json; nothing was changed",
           name=f"no-config{'-resume' if resume else ''}") for resume in ({}, {"--resume": []})],
    Case("train", {"--out": "{gen}/runs/no_checkpoint"}, "a run is already there; pass --resume", name="no-checkpoint"),
    # --resume with a config that differs from the run's: refused, naming the settings
    Case("train", {"--config": None, "--out": "{gen}/runs/valid", "--resume": [], "--set": "ppo.epochs=3"},
         "the run was started with another config (config.json); it differs in ppo.epochs (run: 4, given: 3)",
         name="resume-other-set"),
    Case("train", {"--out": "{gen}/runs/valid", "--resume": []},
         "it differs in network.attention_hidden (run: 2, given: 8)", name="resume-other-config"),
    Case("train", {"--config": None}, "--config is required to start a run", name="no-config-option"),
    # training config files: big integers, a named pipe
    Case("train", {"--config": "{in}/train/huge_int.toml"}, "huge_int.toml: not valid TOML: an integer longer than "
         "4,300 digits"),
    Case("train", {"--config": "{gen}/fifo.yaml"}, "fifo.yaml: training config is a named pipe (FIFO)"),
    # training settings that become array sizes and loop counts: bounded
    Case("train", {"--set": "rollout.max_steps=1000000000"}, "rollout.max_steps must be an integer from 40 to 100,000"),
    Case("train", {"--set": "rollout.robots=[3,100]"}, "rollout.robots must be an integer from 1 to 8, got 100"),
    Case("train", {"--set": "rollout.episodes=1000000000"}, "rollout.episodes must be an integer from 1 to 10,000"),
    Case("train", {"--set": "rollout.lockstep=100000"}, "rollout.lockstep must be an integer from 1 to 256"),
    Case("train", {"--set": "ppo.threads=100000"}, "ppo.threads must be an integer from 1 to 256"),
    Case("train", {"--set": "ppo.epochs=1000000000"}, "ppo.epochs must be an integer from 1 to 1,000"),
    Case("train", {"--set": "evaluation.episodes=1000000000"}, "evaluation.episodes must be an integer from 0 to"),
    Case("train", {"--set": "total_decisions=" + "9" * 40}, "total_decisions must be an integer from 1 to "
         "1,000,000,000, got 9999"),
    Case("train", {"--set": "seed=" + "9" * 40}, "seed must be an integer from 0 to 9,223,372,036,854,775,807"),
    Case("train", {"--set": "rollout.maps=" + json.dumps(["procedural:small"] * 2000)},
         "rollout.maps must name at most 1,000 maps, got 2,000"),
    Case("train", {"--set": "rollout.env.robot.radius_m=1e9"}, "rollout.env: robot.radius_m must be a positive number "
         "of at most"),
    Case("train", {"--set": "rollout.env.max_steps=5"}, "rollout.env.max_steps is not allowed here; use "
         "rollout.max_steps"),
    Case("train", {"--set": "network=5"}, "[network] must be a table of settings, got 5"),
    Case("train", {"--set": "network.node_dim=100000000"}, "network.node_dim must be an integer from 1 to 4,096"),
    Case("train", {"--set": "network.sinkhorn_iters=1000000000"}, "network.sinkhorn_iters must be an integer from 1 "
         "to 1,000"),
    Case("train", {"--set": "network.graph.neighbours=100000000"}, "network.graph.neighbours must be an integer from "
         "1 to 256"),
    # round three: own weights and plug-in planners
    *[Case(command, {"--method": "greedy", "--weights": "{ckpt}/other"},
           "planner 'greedy' takes no weights: --weights (weights=...) is for a learned planner",
           name="weights-classical") for command in ("run", "render", "assign")],
    *[Case(command, {"--method": None, "--weights": "{ckpt}/absent"}, "absent.json: cannot read the policy config",
           name="weights-alone-absent") for command in ("run", "render", "assign")],
    *[Case(command, {"--method": "dahgnn", "--weights": ""}, "weights must be a path prefix", name="weights-empty")
      for command in ("run", "render", "assign")],
    Case("run", {"--method": "ncm", "--weights": "{ckpt}/mismatch"}, "do not match mismatch.json"),
    Case("render", {"--method": "dahgnn-no-type", "--weights": "{ckpt}/truncated"}, "truncated.safetensors: cannot"),
    Case("render", {"--method": None, "--methods": ["greedy", "random"], "--weights": "{ckpt}/other"},
         "--weights with --methods is played by the one learned method among them, and none is"),
    Case("render", {"--method": None, "--methods": ["dahgnn-untrained", "ncm-untrained"], "--weights": "{ckpt}/other"},
         "and 2 are (dahgnn-untrained, ncm-untrained); list exactly one learned method"),
    Case("render", {"--method": None}, "name the planner: --method NAME, --methods NAME NAME..., or --weights PREFIX"),
    *[Case(command, {"--method": "no-such-plug-in"}, "unknown planner 'no-such-plug-in'; known planners:",
           name="unknown-planner") for command in ("run", "render", "assign")],
]  # fmt: skip


def _case_id(case: Case) -> str:
    if case.name:
        return f"{case.command}-{case.name}"
    return f"{case.command}-" + "-".join(f"{k.strip('-')}={v}" for k, v in case.changes.items())


# ---------------------------------------------------------------------------------- fixtures


def _make_corpus() -> object:
    spec = importlib.util.spec_from_file_location("make_corpus", CORPUS / "make_corpus.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The inputs written at test time (``make_corpus.write_generated``), outside the working folder
    (a named pipe there would block its snapshot)."""
    folder = tmp_path_factory.mktemp("gen")
    _make_corpus().write_generated(folder)  # type: ignore[attr-defined]
    return folder


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``mismatch``: a DA-HGNN JSON beside NCM weights; ``truncated``: half an NCM safetensors file;
    ``absent``: nothing; ``huge_*``: NCM weights beside a JSON with one size out of bounds (a field that
    shapes no tensor: Sinkhorn iterations, neighbours, a crop whose pooling cancels it; a network of 61
    million parameters; an integer of 5,000 digits)."""
    from areasearch.models.network import DAHGNN
    from areasearch.models.network_config import NetworkConfig
    from areasearch.models.weights import save_policy

    folder = tmp_path_factory.mktemp("ckpt")
    save_policy(folder / "mismatch", DAHGNN(NetworkConfig()), NetworkConfig())
    save_policy(folder / "other", DAHGNN(NetworkConfig.ncm()), NetworkConfig.ncm())
    shutil.copy(folder / "other.safetensors", folder / "mismatch.safetensors")
    save_policy(folder / "truncated", DAHGNN(NetworkConfig.ncm()), NetworkConfig.ncm())
    data = (folder / "truncated.safetensors").read_bytes()
    (folder / "truncated.safetensors").write_bytes(data[: len(data) // 2])
    for name, changes in (
        ("huge_sinkhorn", {"sinkhorn_iters": 10**9}),
        ("huge_neighbours", {"graph": {"neighbours": 10**9}}),
        ("huge_patch", {"graph": {"patch_cells": 10**6, "patch_pool": 10**6}}),
        ("huge_network", {"rounds": 64, "node_dim": 4096}),
    ):
        doc = json.loads((folder / "other.json").read_text())
        for key, value in changes.items():
            doc["config"][key] = {**doc["config"][key], **value} if isinstance(value, dict) else value
        (folder / f"{name}.json").write_text(json.dumps(doc))
        shutil.copy(folder / "other.safetensors", folder / f"{name}.safetensors")
    text = (folder / "other.json").read_text().replace('"sinkhorn_iters": 10', '"sinkhorn_iters": ' + "9" * 5000)
    (folder / "huge_int.json").write_text(text)
    shutil.copy(folder / "other.safetensors", folder / "huge_int.safetensors")
    return folder


def _workspace(root: Path) -> dict[str, str]:
    """A working folder with outputs a failed command must not touch, and a copy of the corpus."""
    root.mkdir()
    shutil.copytree(CORPUS, root / "in", ignore=shutil.ignore_patterns("*.py", "__pycache__"))
    (root / "existing.png").write_bytes(b"an earlier picture \x00\x01")
    (root / "existing.gif").write_bytes(b"an earlier animation \x00\x02")
    (root / "goals.json").write_text('{"earlier": "goals"}\n')
    (root / "results").mkdir()
    (root / "results" / "notes.txt").write_text("keep me\n")
    (root / "movie.gif").mkdir()
    (root / "other_run").mkdir()
    (root / "other_run" / "config.json").write_text('{"format": "areasearch-eval/1", "seed": 99}\n')
    (root / "other_run" / "episodes.csv").write_text("method,map\n")
    return {"in": str(root / "in"), "ws": str(root)}


def _snapshot(root: Path) -> dict[str, bytes | None]:
    """Every file (its bytes) and folder (None) under ``root``."""
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


def _call(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def _check_error(code: int, out: str, err: str, case: Case, places: dict[str, str] | None = None) -> None:
    assert code != 0, out
    assert "Traceback" not in err and "Traceback" not in out
    lines = err.splitlines()
    assert lines, "no error message"
    assert lines[-1].startswith(("areasearch: error: ", f"areasearch {case.command}: error: ")), err
    if case.argparse:
        assert all(line.startswith(("usage:", " ")) for line in lines[:-1]), err
    else:
        assert len(lines) == 1, err
    expect = case.expect.replace("{ws}", (places or {}).get("ws", "{ws}"))
    assert expect in lines[-1], f"{expect!r} not in {lines[-1]!r}"
    assert len(lines[-1]) <= MAX_LINE + len(str((places or {}).get("ws", ""))) * 2, lines[-1]


# ---------------------------------------------------------------------------------- tests


@pytest.mark.parametrize("case", CASES, ids=_case_id)
def test_bad_input_is_one_clear_error_and_touches_nothing(
    case: Case, tmp_path: Path, checkpoints: Path, generated: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    places = {**_workspace(tmp_path / "ws"), "ckpt": str(checkpoints), "gen": str(generated)}
    before = _snapshot(tmp_path)
    t0 = time.perf_counter()
    code, out, err = _call(case.argv(places), capsys)
    assert time.perf_counter() - t0 < MAX_SECONDS
    _check_error(code, out, err, case, places)
    assert _snapshot(tmp_path) == before


@pytest.mark.parametrize("command", sorted(GOOD))
def test_the_good_arguments_work(command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Each case changes one thing of arguments that work, so its error comes from that change."""
    places = _workspace(tmp_path / "ws")
    before = _snapshot(tmp_path)
    code, _, err = _call(Case(command, {}, "").argv(places), capsys)
    assert code == 0, err
    assert "error" not in err
    changed = {k for k, v in _snapshot(tmp_path).items() if before.get(k, b"absent") != v}
    expected = {
        "run": {"ws/existing.png"},
        "render": {"ws/existing.gif", "ws/existing.png"},
        "eval": {f"ws/results/{name}" for name in ("config.json", "episodes.csv", "curves.jsonl", "curves.png",
                                                   "summary.md", "summary.json", "summary.tex")},
        "assign": {"ws/goals.json"},
        "maps": set(),
        "train": {k for k in changed if k.startswith("ws/run/")}
        | {"ws/run", "ws/run/policy.json", "ws/run/final.json", "ws/run/checkpoint.json"},
    }[command]  # fmt: skip
    assert changed == expected


def test_the_corpus_covers_every_command() -> None:
    assert {case.command for case in CASES} == set(GOOD)
    assert len({_case_id(case) for case in CASES}) == len(CASES)


@pytest.mark.slow
@pytest.mark.parametrize(
    "case",
    [
        Case("run", {"--map": "{in}/maps/truncated.png"}, "not a readable image"),
        Case("eval", {"--maps": "{in}/ros/missing_key.yaml"}, "missing required field(s)"),
        Case("assign", {"--robots": "{in}/robots/nan.json"}, "must be a finite number, got nan"),
        Case("render", {"--robots": "0"}, "argument --robots: expected a positive integer, got 0", argparse=True),
        Case("eval", {"--set": "robot.wheels=4"}, "unknown setting 'robot.wheels'"),
    ],
    ids=_case_id,
)
def test_bad_input_in_a_real_process(case: Case, tmp_path: Path, run_cli: CliRunner) -> None:
    places = _workspace(tmp_path / "ws")
    before = _snapshot(tmp_path)
    result = run_cli(*case.argv(places))
    assert result.returncode == 2
    _check_error(result.returncode, result.stdout, result.stderr, case)
    assert _snapshot(tmp_path) == before


# ---------------------------------------------------------------------------------- read correctly


def _assign(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[dict, str]:  # type: ignore[type-arg]
    code, out, err = _call(argv, capsys)
    assert code == 0, err
    return json.loads(out), err


def test_16_bit_maps_and_exponent_numbers_read_as_their_8_bit_twin(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A 16-bit PGM (maxval 65535) and a YAML with ``resolution: 5e-2`` give the goals of good.yaml."""
    robots = str(CORPUS / "robots" / "good.json")
    reference, _ = _assign(["assign", "--map", str(CORPUS / "ros" / "good.yaml"), "--robots", robots], capsys)
    assert any(r["type"] == "frontier" for r in reference["robots"])
    for name in ("good16.yaml", "exponent.yaml"):
        doc, err = _assign(["assign", "--map", str(CORPUS / "ros" / name), "--robots", robots], capsys)
        assert doc == reference and err == "", name
    image, _ = _assign(
        ["assign", "--map", str(CORPUS / "ros" / "good16.pgm"), "--resolution", "0.05", "--robots", robots], capsys
    )
    assert image["robots"] == reference["robots"]


@pytest.mark.slow
def test_a_huge_yaw_is_normalised(capsys: pytest.CaptureFixture[str]) -> None:
    """yaw 1e308 is a direction like any other: every planner, the learned ones too, gives goals and
    nothing is printed on stderr (no overflow warning, no traceback)."""
    for method in ("greedy", "hungarian", "dahgnn"):
        argv = [
            "assign",
            "--map",
            str(CORPUS / "ros" / "good.yaml"),
            "--robots",
            str(CORPUS / "robots" / "huge_yaw.json"),
        ]
        doc, err = _assign([*argv, "--method", method], capsys)
        assert err == "" and len(doc["robots"]) == 2, method


def test_targets_that_cannot_be_goals_are_reported(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["assign", "--map", str(CORPUS / "ros" / "thick.yaml"), "--robots", str(CORPUS / "robots" / "good.json")]
    doc, err = _assign([*argv, "--targets", str(CORPUS / "robots" / "targets_dropped.json")], capsys)
    reasons = {d["id"]: d["reason"] for d in doc["dropped_targets"]}
    assert reasons == {"wall": "in a wall", "pocket": "unreachable", "behind": "in unknown space"}
    lines = err.splitlines()
    assert len(lines) == 3 and all(line.startswith("areasearch: warning: target '") for line in lines), err
    assert "'wall' at (2.5, 0.6) cannot be a goal (in a wall)" in err
    assert all(r["target"] in (None, "room") for r in doc["robots"])


# ---------------------------------------------------------------------------------- bombs, in a process

BOMBS = [
    Case("assign", {"--map": "{gen}/bomb.yaml"}, "declares 400,000,000 pixels", name="png-bomb"),
    Case("run", {"--map": "{gen}/lying.yaml"}, "declares 900,000,000 pixels", name="pgm-header-lies"),
    Case("eval", {"--maps": "{gen}/bomb6k.yaml"}, "declares 6000 x 6000 pixels", name="png-bomb-6k"),
    Case("assign", {"--map": "{in}/ros/aliases.yaml"}, "anchors and aliases", name="yaml-aliases"),
    Case("run", {"--map": "{gen}/big.yaml"}, "larger than 65,536 bytes", name="yaml-10mb"),
    Case("assign", {"--robots": "{gen}/many_robots.json"}, "at most 8", name="10000-robots"),
    Case("run", {"--map": "{gen}/fifo.yaml"}, "named pipe (FIFO)", name="fifo"),
]


PEAK_WRAPPER = """
import atexit, os, sys
def _peak():
    with open('/proc/self/status') as status:
        kib = next(int(line.split()[1]) for line in status if line.startswith('VmHWM:'))
    with open(os.environ['AREASEARCH_TEST_PEAK_FILE'], 'w') as out:
        out.write(str(kib * 1024))
atexit.register(_peak)
from areasearch.cli import main
sys.exit(main(sys.argv[1:]))
"""
"""Runs the command line and, at exit, writes the process's own peak resident memory (``VmHWM``, kept
per address space, so it starts again at the exec) to the file ``AREASEARCH_TEST_PEAK_FILE`` names.
Not ``ru_maxrss``: Linux carries it across exec, so a child of a test process that holds 1 GB
(after the training tests) reports 1 GB before doing anything."""


def _run_bounded(argv: list[str]) -> tuple[int, str, str, float, int]:
    """``areasearch argv`` in a subprocess: exit status, stdout, stderr, wall seconds, and that
    process's own peak resident memory in bytes (:data:`PEAK_WRAPPER`)."""
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        peak_file = Path(folder) / "peak"
        proc = subprocess.Popen(
            [sys.executable, "-c", PEAK_WRAPPER, *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1", "AREASEARCH_TEST_PEAK_FILE": str(peak_file)},
        )
        try:
            out, err = proc.communicate(timeout=MAX_SECONDS * 2)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            raise
        wall = time.perf_counter() - t0
        peak = int(peak_file.read_text())
    return int(proc.returncode), out, err, wall, peak


@pytest.mark.slow
@pytest.mark.parametrize("case", BOMBS, ids=_case_id)
def test_bombs_are_refused_in_bounded_time_and_memory(case: Case, tmp_path: Path, generated: Path) -> None:
    """Each bomb: one error line, exit 2, nothing touched, within MAX_SECONDS and MAX_RSS_BYTES
    (the peak of every child process so far: it includes the import of PyTorch by a learned planner)."""
    places = {**_workspace(tmp_path / "ws"), "gen": str(generated)}
    before = _snapshot(tmp_path)
    code, out, err, wall, rss = _run_bounded(case.argv(places))
    assert code == 2
    _check_error(code, out, err, case, places)
    assert wall < MAX_SECONDS, wall
    assert rss < MAX_RSS_BYTES, rss
    assert _snapshot(tmp_path) == before


# ---------------------------------------------------------------------------------- one process per folder

HOLDER = """
import sys, time
from areasearch.folderlock import hold_folder
with hold_folder(sys.argv[1]):
    print("held", flush=True)
    time.sleep(600)
"""


def test_a_folder_held_by_another_process_is_refused_naming_its_pid(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """While another process holds the results folder, eval and train into it are refused with one
    line naming the folder and that pid, touching nothing; once it is killed (SIGKILL), the kernel has
    released the lock and eval runs."""
    places = _workspace(tmp_path / "ws")
    results = Path(places["ws"]) / "results"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(results)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        lock = results / ".areasearch.lock"
        assert lock.read_text().split("\n")[0] == str(holder.pid)
        before = _snapshot(tmp_path)
        for command, out in (("eval", "{ws}/results"), ("train", "{ws}/results")):
            case = Case(command, {"--out": out}, f"{results}: in use by another areasearch process (pid {holder.pid})")
            code, stdout, err = _call(case.argv(places), capsys)
            _check_error(code, stdout, err, case, places)
        assert _snapshot(tmp_path) == before
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert (results / ".areasearch.lock").exists()  # left by the killed owner, but no longer locked
    code, _, err = _call(Case("eval", {}, "").argv(places), capsys)
    assert code == 0, err
    assert not (results / ".areasearch.lock").exists()


def _rows(folder: Path) -> list[tuple[str, ...]]:
    from areasearch.harness.evaluate import read_episodes

    return [
        tuple(str(r[k]) for k in ("method", "map", "robots", "episode")) for r in read_episodes(folder / "episodes.csv")
    ]


def test_the_summary_counts_each_episode_once(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Rows written twice into episodes.csv (as concurrent runs of an older version did) are counted
    once by the summary, and the re-run repairs the file."""
    places = _workspace(tmp_path / "ws")
    argv = Case("eval", {"--episodes": "2"}, "").argv(places)
    assert _call(argv, capsys)[0] == 0
    results = Path(places["ws"]) / "results"
    lines = (results / "episodes.csv").read_text().splitlines(keepends=True)
    (results / "episodes.csv").write_text("".join(lines + lines[1:]))
    assert len(_rows(results)) == 4
    assert _call(argv, capsys)[0] == 0
    assert len(_rows(results)) == len(set(_rows(results))) == 2
    assert json.loads((results / "summary.json").read_text())["settings"]["episodes"] == 2


@pytest.mark.slow
def test_two_evals_at_once_one_refuses_and_rows_are_unique(tmp_path: Path) -> None:
    """The same eval started twice on one folder: the second is refused (exit 2, one line naming the
    first one's pid) while the first runs; the rows are unique and a re-run adds none."""
    places = _workspace(tmp_path / "ws")
    results = Path(places["ws"]) / "results"
    argv = Case("eval", {"--episodes": "6", "--max-steps": "300"}, "").argv(places)
    command = [sys.executable, "-m", "areasearch.cli", *argv]
    first = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lock = results / ".areasearch.lock"
    deadline = time.monotonic() + MAX_SECONDS
    while not (lock.exists() and lock.read_text().startswith(str(first.pid))) and time.monotonic() < deadline:
        assert first.poll() is None, first.communicate()[1]
        time.sleep(0.05)
    second = subprocess.run(command, capture_output=True, text=True, timeout=MAX_SECONDS * 2, check=False)
    still_running = first.poll() is None
    _, first_err = first.communicate(timeout=MAX_SECONDS * 4)
    assert first.returncode == 0, first_err
    if still_running:  # (on a very slow machine the first may have ended before the second looked)
        assert second.returncode == 2
        case = Case("eval", {}, f"{results}: in use by another areasearch process (pid {first.pid})")
        _check_error(second.returncode, second.stdout, second.stderr, case, places)
    rows = _rows(results)
    assert len(rows) == len(set(rows)) == 6
    again = subprocess.run(command, capture_output=True, text=True, timeout=MAX_SECONDS * 2, check=False)
    assert again.returncode == 0, again.stderr
    assert _rows(results) == rows


# ---------------------------------------------------------------------------------- diverging training


def _all_finite(folder: Path) -> bool:
    import torch
    from safetensors.torch import load_file

    return all(
        bool(torch.isfinite(t).all()) for path in folder.glob("*.safetensors") for t in load_file(str(path)).values()
    )


@pytest.mark.slow
def test_a_diverging_training_run_stops_with_an_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An absurd learning rate: the losses become NaN at the first update; the run ends with one error
    line and exit 2, and no checkpoint past the start (iteration 0) or policy (none with a NaN weight)
    is written."""
    places = _workspace(tmp_path / "ws")
    case = Case("train", {"--set": "ppo.learning_rate=1e9"}, "training diverged at iteration 1")
    code, _, err = _call(case.argv(places), capsys)
    lines = err.splitlines()
    assert code == 2 and "Traceback" not in err
    assert lines[-1].startswith("areasearch: error: ") and case.expect in lines[-1], err
    assert sum("error" in line for line in lines) == 1, err
    run = Path(places["ws"]) / "run"
    assert json.loads((run / "checkpoint.json").read_text())["iteration"] == 0
    assert not list(run.glob("policy.*")) and not list(run.glob("final.*"))
    assert _all_finite(run)
    assert not (run / ".areasearch.lock").exists()


@pytest.mark.slow
def test_divergence_keeps_the_last_good_checkpoint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, tiny_training: Path
) -> None:
    """The parameters turn NaN at the second update: TrainingDiverged, and the checkpoint of the first
    iteration stays as it was, finite."""
    import torch

    from areasearch.errors import TrainingDiverged
    from areasearch.training import train as train_module

    real = train_module.ppo_update

    def poisoned(model, optimizer, trajectories, config, iteration, *args):  # type: ignore[no-untyped-def]
        stats = real(model, optimizer, trajectories, config, iteration, *args)
        if iteration == 2:
            with torch.no_grad():
                next(model.parameters()).fill_(float("nan"))
        return stats

    monkeypatch.setattr(train_module, "ppo_update", poisoned)
    config = train_module.load_config(tiny_training, {"total_decisions": 40})
    run = tmp_path / "run"
    with pytest.raises(TrainingDiverged, match="training diverged at iteration 2: parameter"):
        train_module.train(config, run, workers=0, log=None, progress=None)
    before = json.loads((run / "checkpoint.json").read_text())
    assert before["iteration"] == 1
    assert _all_finite(run)
    assert not (run / ".areasearch.lock").exists()


# ---------------------------------------------------------------------------------- outputs: devices, write errors


def test_dev_null_as_an_output_is_refused_and_stays_a_device(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--out /dev/null`` of every command that writes is refused before any work; /dev/null is the same
    character device afterwards (as root an atomic write's rename would have replaced it) and no
    temporary file is left in /dev."""
    before = os.stat("/dev/null")
    assert stat.S_ISCHR(before.st_mode)
    places = _workspace(tmp_path / "ws")
    for command in ("run", "assign", "eval", "train"):
        code, _, err = _call(Case(command, {"--out": "/dev/null"}, "").argv(places), capsys)
        assert code == 2 and "/dev/null" in err.splitlines()[-1] and "Traceback" not in err, err
    after = os.stat("/dev/null")
    assert stat.S_ISCHR(after.st_mode)
    assert (after.st_ino, after.st_rdev, after.st_mode) == (before.st_ino, before.st_rdev, before.st_mode)
    assert not [p for p in os.listdir("/dev") if p.startswith(".null")]


def _file_size_limit(limit: int) -> Callable[[], None]:
    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG, not a signal
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply


@pytest.mark.slow
@pytest.mark.parametrize(
    ("command", "what"),
    [("run", "existing.png: cannot write the picture"), ("assign", "goals.json: cannot write the assignment")],
)
def test_a_file_size_limit_is_one_error_and_keeps_the_old_output(command: str, what: str, tmp_path: Path) -> None:
    """Under ``ulimit -f`` (RLIMIT_FSIZE, 200 bytes) the picture or the goals cannot be written: one
    error line (file too large), exit 2, the output that was there unchanged, no temporary file."""
    places = _workspace(tmp_path / "ws")
    before = _snapshot(tmp_path)
    result = subprocess.run(
        [sys.executable, "-m", "areasearch.cli", *Case(command, {}, "").argv(places)],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
        preexec_fn=_file_size_limit(200),
        timeout=MAX_SECONDS * 2,
        check=False,
    )
    last = result.stderr.splitlines()[-1]
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    assert last.startswith("areasearch: error: ") and what in last and "file too large" in last, last
    assert _snapshot(tmp_path) == before


def _fail_writes_to(monkeypatch: pytest.MonkeyPatch, name: str, error: int) -> None:
    """``os.write`` to a file called ``name`` fails with ``error`` (ENOSPC: a full disk)."""
    real = os.write

    def write(fd: int, data: Any) -> int:
        if os.readlink(f"/proc/self/fd/{fd}").endswith("/" + name):
            raise OSError(error, os.strerror(error))
        return real(fd, data)

    monkeypatch.setattr(os, "write", write)


def test_a_full_disk_while_appending_keeps_every_finished_episode(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The disk fills while an episode's curve is appended: one error line naming curves.jsonl, exit 2;
    the episodes already written are all there and no partial line is left; once there is room again
    the same command finishes the run."""
    places = _workspace(tmp_path / "ws")
    results = Path(places["ws"]) / "results"
    assert _call(Case("eval", {}, "").argv(places), capsys)[0] == 0
    rows, curves = (results / "episodes.csv").read_bytes(), (results / "curves.jsonl").read_bytes()
    more = Case("eval", {"--episodes": "3"}, "").argv(places)
    with monkeypatch.context() as patch:
        _fail_writes_to(patch, "curves.jsonl", errno.ENOSPC)
        code, _, err = _call(more, capsys)
    assert code == 2 and "Traceback" not in err
    assert err.splitlines()[-1].startswith("areasearch: error: "), err
    assert "curves.jsonl: cannot write the curve log: no space left on the device" in err.splitlines()[-1]
    assert (results / "episodes.csv").read_bytes() == rows and (results / "curves.jsonl").read_bytes() == curves
    assert not list(results.glob(".*.tmp")) and not (results / ".areasearch.lock").exists()
    assert _call(more, capsys)[0] == 0
    assert len(_rows(results)) == 3


def test_a_full_disk_at_a_rename_keeps_the_old_summary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``os.replace`` of a summary fails (ENOSPC): one error line naming summary.md; the summary of the
    earlier run is as it was and no temporary file is left."""
    places = _workspace(tmp_path / "ws")
    results = Path(places["ws"]) / "results"
    assert _call(Case("eval", {}, "").argv(places), capsys)[0] == 0
    summary = (results / "summary.md").read_bytes()
    real = os.replace

    def replace(src: Any, dst: Any, **kwargs: Any) -> None:
        if str(dst).endswith("summary.md"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(src, dst, **kwargs)

    monkeypatch.setattr(os, "replace", replace)
    code, _, err = _call(Case("eval", {"--episodes": "2"}, "").argv(places), capsys)
    assert code == 2 and err.splitlines()[-1].endswith("summary.md: cannot write the file: no space left on the device")
    assert (results / "summary.md").read_bytes() == summary
    assert not list(results.glob(".*.tmp"))


def _read_only(monkeypatch: pytest.MonkeyPatch, folder: Path) -> None:
    """Every opening of a file under ``folder`` for writing fails with EROFS (a read-only file system:
    the tests run as root, which chmod does not stop)."""
    import builtins
    import io

    inside = str(folder.resolve())
    real_os_open, real_open = os.open, builtins.open
    writing = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_APPEND

    def refuse(path: Any) -> None:
        if isinstance(path, (str, Path)) and os.path.abspath(path).startswith(inside):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))

    def os_open(path: Any, flags: int, *args: Any, **kwargs: Any) -> int:
        if flags & writing:
            refuse(path)
        return real_os_open(path, flags, *args, **kwargs)

    def open_(file: Any, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        if any(c in mode for c in "wax+"):
            refuse(file)
        return real_open(file, mode, *args, **kwargs)

    monkeypatch.setattr(os, "open", os_open)
    monkeypatch.setattr(builtins, "open", open_)
    monkeypatch.setattr(io, "open", open_)


def test_a_finished_folder_on_read_only_media_is_summarised(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Re-running a finished evaluation whose folder cannot be written prints its summary, writing
    nothing (no lock file, no file rewritten); a run that would have to play episodes there ends with one
    error line naming the read-only file system, the folder as it was."""
    places = _workspace(tmp_path / "ws")
    results = Path(places["ws"]) / "results"
    argv = Case("eval", {}, "").argv(places)
    assert _call(argv, capsys)[0] == 0
    before = _snapshot(results)
    _read_only(monkeypatch, results)
    code, out, err = _call(argv, capsys)
    assert code == 0, err
    assert "| greedy |" in out and "error" not in err
    assert _snapshot(results) == before
    code, _, err = _call(Case("eval", {"--episodes": "2"}, "").argv(places), capsys)
    assert code == 2 and "read-only file system" in err.splitlines()[-1] and "Traceback" not in err, err
    assert _snapshot(results) == before


# ---------------------------------------------------------------------------------- a map changed under a resume


def test_a_resume_on_a_changed_map_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """config.json pins the SHA-256 of each map's content: a resume after the map's image changed is
    refused naming the map, and works again once the image is restored. A folder written before maps
    were pinned (no ``maps``) is resumed; re-running it with nothing to play leaves config.json as it
    was, and the hashes are added when episodes are played."""
    places = _workspace(tmp_path / "ws")
    results = Path(places["ws"]) / "results"
    image = Path(places["in"]) / "ros" / "good.png"
    argv = Case("eval", {}, "").argv(places)
    assert _call(argv, capsys)[0] == 0
    config = json.loads((results / "config.json").read_text())
    assert list(config["maps"]) == ["good"] and len(config["maps"]["good"]) == 64
    original = image.read_bytes()
    pixels = np.array(Image.open(image))
    pixels[30:33, 5:8] = 0  # a pillar in the room
    Image.fromarray(pixels).save(image)
    before = _snapshot(tmp_path)
    case = Case("eval", {"--episodes": "2"}, "config.json: map good has changed since its episodes were played")
    code, out, err = _call(case.argv(places), capsys)
    _check_error(code, out, err, case, places)
    assert _snapshot(tmp_path) == before
    image.write_bytes(original)
    assert _call(argv, capsys)[0] == 0
    # a folder of an earlier version, without the hashes
    del config["maps"]
    (results / "config.json").write_text(json.dumps(config, indent=2) + "\n")
    old = (results / "config.json").read_bytes()
    assert _call(argv, capsys)[0] == 0
    assert (results / "config.json").read_bytes() == old
    assert _call(case.argv(places), capsys)[0] == 0
    assert "good" in json.loads((results / "config.json").read_text())["maps"]


# ---------------------------------------------------------------------------------- the Python API


API_CASES = [
    (
        {"poses": [["1.0", "1.0", "0"]]},
        "poses must be an (N, 3) array of x, y, yaw (metres, radians) (real numbers), "
        "got '1.0' in [['1.0', '1.0', '0']]",
    ),
    ({"poses": [[1 + 2j, 1.0, 0.0]]}, "(real numbers), got (1+2j) in"),
    ({"poses": [[np.bool_(True), 1.0, 0.0]]}, "(real numbers), got np.True_ in"),
    ({"poses": np.array([[True, True, False]])}, "got bool values"),
    ({"poses": [[10**400, 1.0, 0.0]]}, "poses must be a finite number"),
    ({"targets": [["1", "2"]]}, "targets must be an (N, 2) array of x, y in metres (real numbers), got '1'"),
    ({"seed": np.bool_(True)}, "seed must be a non-negative integer, got np.True_"),
    ({"seed": "3"}, "seed must be a non-negative integer, got '3'"),
    ({"radius_m": "0.2"}, "radius_m must be a number, got '0.2'"),
    ({"radius_m": 1j}, "radius_m must be a number, got 1j"),
    ({"sensor_range_m": 10**400}, "sensor_range_m must be a finite number"),
    ({"path_step_m": 1e308}, "path_step_m must be a positive number of at most 100 m"),
    ({"progress": "half"}, "progress must be a number in [0, 1], got 'half'"),
    ({"method": 3}, "method must be a planner name or a GoalPlanner (with assign and reset), got 3"),
    ({"planner_settings": "weights"}, "planner_settings must be a mapping of keyword settings"),
    ({"robot_names": "ab"}, "robot_names must be a list of strings, one per robot"),
    ({"config": {"world": {}}}, "config must be an areasearch.config.SearchConfig"),
    ({"grid": "ARRAY", "resolution": np.bool_(True)}, "grid: resolution must be a number of metres per cell"),
    ({"grid": "ARRAY", "resolution": "0.05"}, "grid: resolution must be a number of metres per cell, got '0.05'"),
    ({"grid": "ARRAY", "resolution": 0.05, "origin": [1j, 0.0]}, "grid: origin must be a list of numbers"),
]
"""``assign_goals`` arguments (besides a good map and poses) and the message of the error they raise."""


@pytest.mark.parametrize(("changes", "expect"), API_CASES, ids=[str(i) for i in range(len(API_CASES))])
def test_the_python_api_checks_what_the_command_line_checks(changes: dict[str, Any], expect: str) -> None:
    """``assign_goals`` refuses text, booleans, complex numbers and numbers beyond the floats wherever a
    number belongs, and arguments of the wrong kind, with one ConfigError or MapError naming the
    argument: never a TypeError or OverflowError from inside."""
    from areasearch.errors import AreaSearchError
    from areasearch.service.assign import assign_goals

    arguments: dict[str, Any] = {"grid": str(CORPUS / "ros" / "good.yaml"), "poses": [[1.0, 1.0, 0.0]], **changes}
    if arguments["grid"] == "ARRAY":
        arguments["grid"] = np.zeros((30, 30), dtype=np.int8)
        arguments["poses"] = [[0.7, 0.7, 0.0]]
    with pytest.raises(AreaSearchError) as caught:
        assign_goals(**arguments)
    assert expect in str(caught.value)


def test_numpy_numbers_are_numbers_to_the_python_api() -> None:
    """np.float32 poses (as a ROS message gives them), NumPy scalars for the resolution, seed, radius and
    thresholds give the goals that Python floats give."""
    from areasearch.service.assign import assign_goals, occupancy_from_array

    yaml_map = str(CORPUS / "ros" / "good.yaml")
    poses = [[1.0, 1.0, 0.0], [1.6, 2.0, 0.0]]
    reference = [a.goal_xy for a in assign_goals(yaml_map, poses, radius_m=0.18, seed=3)]
    as_numpy = assign_goals(
        yaml_map, np.array(poses, dtype=np.float32), radius_m=np.float32(0.18), seed=np.int64(3), progress=np.float32(0)
    )
    assert [a.goal_xy for a in as_numpy] == reference
    grid = np.zeros((30, 30), dtype=np.int8)
    grid[[0, -1], :] = 100
    a = occupancy_from_array(grid, 0.05, free_thresh=np.float32(0.196), occupied_thresh=np.float64(0.65))
    b = occupancy_from_array(grid, np.float32(0.05))
    assert (a.free == b.free).all() and (a.occupied == b.occupied).all()


@pytest.mark.parametrize(
    ("thresholds", "expect"),
    [
        ({"free_thresh": 2.0}, "need 0 <= free_thresh < occupied_thresh <= 1, got free_thresh=2"),
        ({"occupied_thresh": 5}, "got free_thresh=0.196, occupied_thresh=5"),
        ({"free_thresh": float("nan")}, "free_thresh must be a number from 0 to 1, got nan"),
        ({"free_thresh": "x"}, "free_thresh must be a number from 0 to 1, got 'x'"),
        ({"occupied_thresh": np.bool_(True)}, "occupied_thresh must be a number from 0 to 1"),
    ],
)
def test_map_thresholds_outside_0_to_1_are_refused(thresholds: dict[str, Any], expect: str) -> None:
    from areasearch.errors import MapError
    from areasearch.service.assign import occupancy_from_array

    with pytest.raises(MapError, match=re.escape(expect)):
        occupancy_from_array(np.zeros((30, 30), dtype=np.int8), 0.05, **thresholds)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["huge_patch", "huge_neighbours", "huge_network"])
def test_a_policy_of_absurd_sizes_is_refused_in_bounded_time_and_memory(
    name: str, tmp_path: Path, checkpoints: Path
) -> None:
    """A policy JSON beside valid weights with a size out of bounds, played by ``assign`` in a process
    of its own: one error line, exit 2, within MAX_SECONDS and MAX_RSS_BYTES (nothing is allocated
    before the JSON's sizes and the weights' header are checked)."""
    places = {**_workspace(tmp_path / "ws"), "ckpt": str(checkpoints)}
    case = Case("assign", {"--method": "ncm-untrained", "--weights": f"{{ckpt}}/{name}"}, f"{name}.json: ")
    code, out, err, wall, rss = _run_bounded(case.argv(places))
    assert code == 2
    _check_error(code, out, err, case, places)
    assert wall < MAX_SECONDS, wall
    assert rss < MAX_RSS_BYTES, rss
