"""The bad-input corpus (``tests/bad_inputs/``, written by its ``make_corpus.py``) run through every
command of the CLI: each case must end with one ``areasearch: error: ...`` line naming what is wrong,
a non-zero exit, no traceback, and must leave every file of the working folder as it was (existing
outputs, the inputs, no stray temporary file).

A case is a command's good arguments (:data:`GOOD`) with one option changed: ``Case(command,
{option: value}, expected text)``. A new command joins by adding its good arguments to :data:`GOOD`
and its rows to :data:`CASES`; a new bad input by adding a file to the corpus and a row. Placeholders:
``{in}`` the corpus, ``{ws}`` the working folder (with the existing outputs), ``{ckpt}`` the
checkpoints the fixture writes. Cases run ``areasearch.cli.main`` in this process (an exception
escaping it is the traceback a user would see); a few run it as a subprocess, as a user would.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from areasearch.cli import main

CORPUS = Path(__file__).resolve().parent / "bad_inputs"

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
        return [a.format(**places) for a in args]


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
]


def _map_cases() -> list[Case]:
    cases = []
    for command, option in MAP_OPTION.items():
        for name, path, expect in BROKEN_MAPS:
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
    Case("assign", {"--map": "{in}/ros/good.png", "--resolution": "0"}, "resolution must be in (0, 10.0]"),
    Case("assign", {"--map": "{in}/ros/good.png", "--resolution": "-0.05"}, "resolution must be in (0, 10.0]"),
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
    # output paths that cannot take the output
    Case("run", {"--out": "{ws}/results"}, "picture path is a folder"),
    Case("run", {"--out": "{ws}/no_such_folder/ep.png"}, "folder for the picture does not exist"),
    Case("render", {"--out": "{ws}/movie.gif"}, "animation path is a folder"),
    Case("render", {"--out": "{ws}/existing.png"}, "animation must be a .gif or .mp4 file"),
    Case("eval", {"--out": "{ws}/existing.png"}, "output path is an existing file; give a folder"),
    Case("eval", {"--out": "{ws}/other_run"}, "holds episodes of a run with other settings"),
    Case("assign", {"--out": "{ws}/results"}, "assignment path is a folder"),
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
    Case("train", {"--out": "{ws}/existing.png"}, "the run folder is a file"),
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


def _check_error(code: int, out: str, err: str, case: Case) -> None:
    assert code != 0, out
    assert "Traceback" not in err and "Traceback" not in out
    lines = err.splitlines()
    assert lines, "no error message"
    assert lines[-1].startswith(("areasearch: error: ", f"areasearch {case.command}: error: ")), err
    if case.argparse:
        assert all(line.startswith(("usage:", " ")) for line in lines[:-1]), err
    else:
        assert len(lines) == 1, err
    assert case.expect in lines[-1], f"{case.expect!r} not in {lines[-1]!r}"


# ---------------------------------------------------------------------------------- tests


@pytest.mark.parametrize("case", CASES, ids=_case_id)
def test_bad_input_is_one_clear_error_and_touches_nothing(
    case: Case, tmp_path: Path, checkpoints: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    places = {**_workspace(tmp_path / "ws"), "ckpt": str(checkpoints)}
    before = _snapshot(tmp_path)
    code, out, err = _call(case.argv(places), capsys)
    _check_error(code, out, err, case)
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
