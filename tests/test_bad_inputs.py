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

import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from areasearch.cli import main

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
    # issue 21: lossy images, YAML bombs and odd values, decompression bombs, not-a-file paths
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
    Case("render", {"--fps": "-1"}, "fps must be positive"),
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
    Case("assign", {"--radius-m": "0"}, "robot.radius_m must be a positive number"),
    Case("assign", {"--radius-m": "-0.1"}, "robot.radius_m must be a positive number"),
    Case("assign", {"--sensor-range-m": "-3"}, "camera.max_range_m must be a positive number"),
    Case("assign", {"--map": "{in}/ros/good.png", "--resolution": "0"}, "resolution must be in [0.001, 10.0]"),
    Case("assign", {"--map": "{in}/ros/good.png", "--resolution": "-0.05"}, "resolution must be in [0.001, 10.0]"),
    Case("assign", {"--map": "{in}/ros/good.png", "--resolution": "1e-300"}, "resolution must be in [0.001, 10.0]"),
    Case("assign", {"--map": "{in}/ros/good.png", "--resolution": "0.05", "--origin": ["1e300", "0"]},
         "origin (1e+300, 0) lies farther than 1e+07 m"),
    Case("assign", {"--map": "{in}/ros/jpeg_named.png", "--resolution": "0.05"}, "a JPEG image by its content"),
    Case("assign", {"--map": "{gen}/bomb.png", "--resolution": "0.05"}, "declares 400,000,000 pixels"),
    Case("assign", {"--map": "{gen}/lying.pgm", "--resolution": "0.05"}, "declares 900,000,000 pixels"),
    Case("assign", {"--map": "{in}/ros/good.png", "--resolution": "nan"}, "resolution must be a number"),
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
    # issue 21: extreme numbers, huge counts, overlapping footprints, unknown top-level keys
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
    Case("assign", {"--out": "{ws}/goals.json/sub.json"}, "goals.json is a file, not a folder"),
    Case("train", {"--out": "{ws}/existing.png/run"}, "cannot make the folder there: {ws}/existing.png is a file"),
    # checkpoints: a JSON that does not match its weights, a truncated safetensors file
    Case("assign", {"--method": "dahgnn-untrained", "--weights": "{ckpt}/mismatch"}, "do not match mismatch.json"),
    Case("assign", {"--method": "ncm-untrained", "--weights": "{ckpt}/truncated"}, "truncated.safetensors: cannot"),
    Case("assign", {"--method": "ncm-untrained", "--weights": "{ckpt}/absent"}, "absent.json: cannot read the policy"),
    Case("assign", {"--method": "greedy", "--weights": "{ckpt}/truncated"}, "unexpected keyword argument 'weights'"),
    # training configs and run folders
    Case("train", {"--config": "{in}/train/missing.toml"}, "missing.toml: cannot read the training config"),
    Case("train", {"--config": "{in}/train/truncated.toml"}, "not valid TOML"),
    Case("train", {"--config": "{in}/train/wrong_type.toml"}, "ppo.epochs must be an integer"),
    Case("train", {"--config": "{in}/train/unknown_key.toml"}, "unknown setting ppo.epoch"),
    Case("train", {"--config": "{in}/train/zero_robots.toml"}, "rollout.robots must be an integer >= 1"),
    Case("train", {"--config": "{in}/train/negative_count.toml"}, "total_decisions must be an integer >= 1"),
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
    Case("assign", {"--set": "robot.radius_m=0.2"}, "--set robot.radius_m=... is not allowed here; use --radius-m"),
    Case("assign", {"--set": "camera.max_range_m=4"}, "is not allowed here; use --sensor-range-m"),
    Case("train", {"--device": "tpu"}, "invalid choice: 'tpu'", argparse=True),
    # the Ray backend
    Case("eval", {"--address": "127.0.0.1:1"}, "--address is for --backend ray"),
    Case("eval", {"--backend": "ray", "--address": "127.0.0.1:1"}, "no Ray cluster reachable there"),
    Case("eval", {"--backend": "ray", "--address": "nowhere"}, "--address must be host:port"),
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
    ``absent``: nothing."""
    from areasearch.dahgnn import DAHGNN, NetworkConfig, save_policy

    folder = tmp_path_factory.mktemp("ckpt")
    save_policy(folder / "mismatch", DAHGNN(NetworkConfig()), NetworkConfig())
    save_policy(folder / "other", DAHGNN(NetworkConfig.ncm()), NetworkConfig.ncm())
    shutil.copy(folder / "other.safetensors", folder / "mismatch.safetensors")
    save_policy(folder / "truncated", DAHGNN(NetworkConfig.ncm()), NetworkConfig.ncm())
    data = (folder / "truncated.safetensors").read_bytes()
    (folder / "truncated.safetensors").write_bytes(data[: len(data) // 2])
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
def test_bad_input_in_a_real_process(case: Case, tmp_path: Path) -> None:
    places = _workspace(tmp_path / "ws")
    before = _snapshot(tmp_path)
    result = subprocess.run(
        [sys.executable, "-m", "areasearch.cli", *case.argv(places)],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        timeout=120,
        check=False,
    )
    assert result.returncode == 2
    _check_error(result.returncode, result.stdout, result.stderr, case)
    assert _snapshot(tmp_path) == before


# ---------------------------------------------------------------------------------- issue 21: read correctly


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


# ---------------------------------------------------------------------------------- issue 21: bombs, in a process

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


# ---------------------------------------------------------------------------------- issue 21: one process per folder

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
    from areasearch.evaluate import read_episodes

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


# ---------------------------------------------------------------------------------- issue 21: diverging training


def _all_finite(folder: Path) -> bool:
    import torch
    from safetensors.torch import load_file

    return all(
        bool(torch.isfinite(t).all()) for path in folder.glob("*.safetensors") for t in load_file(str(path)).values()
    )


@pytest.mark.slow
def test_a_diverging_training_run_stops_with_an_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An absurd learning rate: the losses become NaN at the first update; the run ends with one error
    line and exit 2, and no checkpoint or policy (none with a NaN weight) is written."""
    places = _workspace(tmp_path / "ws")
    case = Case("train", {"--set": "ppo.learning_rate=1e9"}, "training diverged at iteration 1")
    code, _, err = _call(case.argv(places), capsys)
    lines = err.splitlines()
    assert code == 2 and "Traceback" not in err
    assert lines[-1].startswith("areasearch: error: ") and case.expect in lines[-1], err
    assert sum("error" in line for line in lines) == 1, err
    run = Path(places["ws"]) / "run"
    assert not (run / "checkpoint.json").exists() and not list(run.glob("policy.*")) and not list(run.glob("final.*"))
    assert _all_finite(run)
    assert not (run / ".areasearch.lock").exists()


@pytest.mark.slow
def test_divergence_keeps_the_last_good_checkpoint(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The parameters turn NaN at the second update: TrainingDiverged, and the checkpoint of the first
    iteration stays as it was, finite."""
    import torch

    from areasearch import train as train_module
    from areasearch.errors import TrainingDiverged

    real = train_module.ppo_update

    def poisoned(model, optimizer, trajectories, config, iteration, aux, runner=None):  # type: ignore[no-untyped-def]
        stats = real(model, optimizer, trajectories, config, iteration, aux, runner)
        if iteration == 2:
            with torch.no_grad():
                next(model.parameters()).fill_(float("nan"))
        return stats

    monkeypatch.setattr(train_module, "ppo_update", poisoned)
    config = train_module.load_config(CORPUS / "train" / "good.toml", {"total_decisions": 40})
    run = tmp_path / "run"
    with pytest.raises(TrainingDiverged, match="training diverged at iteration 2: parameter"):
        train_module.train(config, run, workers=0, log=None, progress=None)
    before = json.loads((run / "checkpoint.json").read_text())
    assert before["iteration"] == 1
    assert _all_finite(run)
    assert not (run / ".areasearch.lock").exists()
