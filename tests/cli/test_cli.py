"""Tests of the ``areasearch`` command line, run in a subprocess as a user would."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from areasearch.sim.scene import bundled_index
from areasearch.sim.splits import map_split, split_maps

CliRunner = Callable[..., subprocess.CompletedProcess[str]]

COMMANDS = ("run", "maps", "eval", "render", "assign", "train")
ERROR_PREFIXES = ("areasearch: error:",)
"""The start of the one error line of every bad input, a malformed command line included."""
_SMALL_BY_AREA = sorted((e for e in bundled_index() if e["size_class"] == "small"), key=lambda e: e["free_area_m2"])
SMALL_MAP = _SMALL_BY_AREA[0]["id"]
LARGEST_SMALL_MAP = _SMALL_BY_AREA[-1]["id"]
_SMALL_IDS = {e["id"] for e in _SMALL_BY_AREA}
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _error_line(result: subprocess.CompletedProcess[str], *, argparse_error: bool = False) -> str:
    """Check a failed run: non-zero exit, no traceback, one error line; return that line."""
    assert result.returncode != 0, result.stdout
    assert "Traceback" not in result.stderr, result.stderr
    assert "Traceback" not in result.stdout, result.stdout
    lines = result.stderr.splitlines()
    errors = [line for line in lines if line.startswith(ERROR_PREFIXES)]
    assert len(errors) == 1, result.stderr
    if not argparse_error:
        # Our own errors: that single line is all of stderr.
        assert lines == errors, result.stderr
    else:
        assert lines[-1] == errors[0], result.stderr
    return errors[0]


def _main_inprocess(capsys: pytest.CaptureFixture[str], *args: str) -> subprocess.CompletedProcess[str]:
    """Call ``areasearch.cli.main`` in this process; an exception escaping it is a user-visible traceback."""
    from areasearch.cli import main

    code = main(list(args))
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(list(args), code, out, err)


# ---------------------------------------------------------------------------------- help and maps


def test_python_m_entry_present(root: Path) -> None:
    source = root / "src" / "areasearch" / "cli" / "__main__.py"
    assert "sys.exit(main())" in source.read_text()


def test_help_lists_subcommands(run_cli: CliRunner) -> None:
    result = run_cli("--help")
    assert result.returncode == 0, result.stderr
    assert "run" in result.stdout.split()
    assert "maps" in result.stdout.split()


def test_no_subcommand_is_an_error(run_cli: CliRunner) -> None:
    result = run_cli()
    _error_line(result, argparse_error=True)


def test_maps_lists_every_bundled_map(run_cli: CliRunner) -> None:
    result = run_cli("maps")
    assert result.returncode == 0, result.stderr
    rows = {line.split()[0]: line.split()[1] for line in result.stdout.splitlines()[1:-1]}
    index = bundled_index()
    assert rows == {e["id"]: e["size_class"] for e in index}
    assert f"{len(index)} maps" in result.stdout.splitlines()[-1]


def test_maps_size_filter(run_cli: CliRunner) -> None:
    result = run_cli("maps", "--size", "small")
    assert result.returncode == 0, result.stderr
    rows = [line.split() for line in result.stdout.splitlines()[1:-1]]
    expected = sorted(e["id"] for e in bundled_index() if e["size_class"] == "small")
    assert sorted(row[0] for row in rows) == expected
    assert {row[1] for row in rows} == {"small"}


def test_maps_json(run_cli: CliRunner) -> None:
    result = run_cli("maps", "--json", "--size", "medium", "large")
    assert result.returncode == 0, result.stderr
    entries = json.loads(result.stdout)
    assert isinstance(entries, list)
    expected = [e for e in bundled_index() if e["size_class"] in ("medium", "large")]
    assert entries == [{**e, "split": map_split(e["id"])} for e in expected]
    assert all(e["license"] and e["source_repo"] for e in entries)


@pytest.mark.parametrize("split", ["train", "val", "test"])
def test_maps_shows_the_split_and_filters_by_it(split: str, run_cli: CliRunner) -> None:
    everything = run_cli("maps")
    rows = {line.split()[0]: line.split()[2] for line in everything.stdout.splitlines()[1:-1]}
    assert everything.stdout.splitlines()[0].split()[:3] == ["id", "class", "split"]
    assert rows == {e["id"]: map_split(e["id"]) for e in bundled_index()}
    result = run_cli("maps", "--split", split, "--size", "small")
    assert result.returncode == 0, result.stderr
    shown = [line.split() for line in result.stdout.splitlines()[1:-1]]
    assert sorted(row[0] for row in shown) == sorted(m for m in split_maps(split) if m in _SMALL_IDS)
    assert {(row[1], row[2]) for row in shown} == {("small", split)}


def test_eval_help_names_the_bundled_splits(run_cli: CliRunner) -> None:
    result = run_cli("eval", "--help")
    assert result.returncode == 0, result.stderr
    text = " ".join(result.stdout.split())
    for spec in ("bundled:train", "bundled:val", "bundled:test"):
        assert f"'{spec}'" in text, spec


# ---------------------------------------------------------------------------------- run


def _run_episode(tmp: Path, name: str, run_cli: CliRunner) -> tuple[dict[str, object], bytes]:
    out = tmp / name
    result = run_cli("run", "--map", SMALL_MAP, "--max-steps", "50", "--seed", "1", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    # progress off a terminal: plain lines, the last one the whole episode
    assert "\r" not in result.stderr and result.stderr.splitlines()[-1].startswith("run: 50/50 steps  "), result.stderr
    summary = json.loads(result.stdout)
    assert summary["picture"] == str(out)
    return summary, out.read_bytes()


Episode = tuple[dict[str, object], bytes]


@pytest.fixture(scope="module")
def episodes(tmp_path_factory: pytest.TempPathFactory, run_cli: CliRunner) -> tuple[Episode, Episode]:
    """The same run twice (seed 1), into two files of one folder."""
    tmp = tmp_path_factory.mktemp("episodes")
    return _run_episode(tmp, "ep.png", run_cli), _run_episode(tmp, "ep2.png", run_cli)


def test_run_writes_png_and_metrics(episodes: tuple[Episode, Episode]) -> None:
    (summary, data), _ = episodes
    assert data.startswith(PNG_SIGNATURE)
    with Image.open(io.BytesIO(data)) as image:
        image.load()
        assert image.format == "PNG"
        assert image.width > 10 and image.height > 10
    assert summary["map"] == SMALL_MAP
    assert summary["size_class"] == "small"
    assert summary["seed"] == 1
    assert summary["steps"] == 50
    explored = summary["explored_pct"]
    assert isinstance(explored, float | int)
    assert 0.0 <= explored <= 100.0
    assert 0.0 <= summary["covered_pct"] <= 100.0


def test_run_same_seed_same_result(episodes: tuple[Episode, Episode]) -> None:
    (first, first_png), (second, second_png) = episodes
    first, second = dict(first), dict(second)
    assert first.pop("picture") != second.pop("picture")
    assert first == second
    assert first_png == second_png


def test_run_writes_no_temporary_files(episodes: tuple[Episode, Episode]) -> None:
    (first, _), _ = episodes
    folder = Path(str(first["picture"])).parent
    assert sorted(p.name for p in folder.iterdir()) == ["ep.png", "ep2.png"]


# ---------------------------------------------------------------------------------- bad inputs


def _map_folder(tmp_path: Path, name: str, pixels: np.ndarray | None = None, text: str | None = None) -> Path:
    folder = tmp_path / "maps"
    folder.mkdir(exist_ok=True)
    path = folder / name
    if text is not None:
        path.write_text(text)
    else:
        Image.fromarray(pixels).save(path)
    (folder / "index.json").write_text(json.dumps({"maps": [{"file": name, "resolution_m_per_px": 0.05}]}))
    return path


def _run_fail(run_cli: CliRunner, tmp_path: Path, *args: str, argparse_error: bool = False) -> str:
    """Run ``areasearch run`` expecting a clean failure; unless ``--out`` is given, check nothing was written."""
    default_out = tmp_path / "ep.png"
    own_out = "--out" in args
    if not own_out:
        args = (*args, "--out", str(default_out))
    result = run_cli("run", "--max-steps", "5", *args)
    line = _error_line(result, argparse_error=argparse_error)
    if not own_out:
        assert not default_out.exists()
    return line


def test_error_missing_map_file(tmp_path: Path, run_cli: CliRunner) -> None:
    missing = tmp_path / "nowhere" / "lost_map.png"
    line = _run_fail(run_cli, tmp_path, "--map", str(missing))
    assert str(missing) in line


def test_error_file_not_an_image(tmp_path: Path, run_cli: CliRunner) -> None:
    path = _map_folder(tmp_path, "fake.png", text="definitely not a PNG\n")
    line = _run_fail(run_cli, tmp_path, "--map", str(path))
    assert "fake.png" in line


def test_error_png_without_free_cell(tmp_path: Path, run_cli: CliRunner) -> None:
    path = _map_folder(tmp_path, "blank.png", pixels=np.zeros((16, 16), dtype=np.uint8))
    line = _run_fail(run_cli, tmp_path, "--map", str(path))
    assert "blank" in line
    assert "free" in line


def test_error_ros_yaml_missing_key(tmp_path: Path, run_cli: CliRunner) -> None:
    pixels = np.zeros((20, 20), dtype=np.uint8)
    pixels[2:18, 2:18] = 254
    Image.fromarray(pixels).save(tmp_path / "floor.pgm")
    yaml_path = tmp_path / "floor.yaml"
    data = {"image": "floor.pgm", "resolution": 0.05, "origin": [0, 0, 0], "negate": 0, "free_thresh": 0.196}
    yaml_path.write_text(yaml.safe_dump(data))
    line = _run_fail(run_cli, tmp_path, "--map", str(yaml_path))
    assert "occupied_thresh" in line
    assert "floor.yaml" in line


def test_error_ros_yaml_syntax_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    yaml_path = tmp_path / "broken.yaml"
    yaml_path.write_text("image: [floor.pgm\nresolution: 0.05\n")
    out = str(tmp_path / "x.png")
    result = _main_inprocess(capsys, "run", "--map", str(yaml_path), "--max-steps", "5", "--out", out)
    line = _error_line(result)
    assert "broken.yaml" in line


@pytest.mark.parametrize("map_id", [SMALL_MAP, LARGEST_SMALL_MAP])
def test_error_too_many_robots(tmp_path: Path, map_id: str, run_cli: CliRunner) -> None:
    line = _run_fail(run_cli, tmp_path, "--map", map_id, "--robots", "8", "--set", "robot.radius_m=1.0")
    assert map_id in line
    assert "radius 1.0" in line


def test_error_negative_radius(tmp_path: Path, run_cli: CliRunner) -> None:
    line = _run_fail(run_cli, tmp_path, "--map", SMALL_MAP, "--set", "robot.radius_m=-0.1")
    assert "robot.radius_m" in line


@pytest.mark.parametrize(
    ("args", "field"),
    [(("--robots", "0"), "--robots"), (("--robots", "9"), "--robots"), (("--max-steps", "0"), "--max-steps")],
)
def test_error_bad_counts(tmp_path: Path, args: tuple[str, str], field: str, run_cli: CliRunner) -> None:
    line = _run_fail(run_cli, tmp_path, "--map", SMALL_MAP, *args, argparse_error=True)
    assert field in line


def test_error_unknown_set_key(tmp_path: Path, run_cli: CliRunner) -> None:
    line = _run_fail(run_cli, tmp_path, "--map", SMALL_MAP, "--set", "robot.wheels=3")
    assert "wheels" in line


def test_error_set_without_equals(tmp_path: Path, run_cli: CliRunner) -> None:
    line = _run_fail(run_cli, tmp_path, "--map", SMALL_MAP, "--set", "robot.radius_m")
    assert "--set" in line


# The cases below are extra findings; they call main() in-process (an exception escaping main() is the
# traceback a user would see) to keep the subprocess count, and so the runtime, down.


@pytest.mark.parametrize("setting", ["num_robots=9", "max_steps=0"])
def test_error_set_duplicates_option(tmp_path: Path, capsys: pytest.CaptureFixture[str], setting: str) -> None:
    out = str(tmp_path / "x.png")
    result = _main_inprocess(capsys, "run", "--map", SMALL_MAP, "--max-steps", "5", "--set", setting, "--out", out)
    line = _error_line(result)
    assert setting.partition("=")[0] in line


@pytest.mark.parametrize(
    "setting",
    ["robot=1", "camera=null", "success_fraction=abc", "camera.hfov_deg=abc", "reward.explore_per_m2=abc",
     "targets.count=true"],
)  # fmt: skip
def test_error_set_wrong_type(tmp_path: Path, capsys: pytest.CaptureFixture[str], setting: str) -> None:
    out = str(tmp_path / "x.png")
    result = _main_inprocess(capsys, "run", "--map", SMALL_MAP, "--max-steps", "5", "--set", setting, "--out", out)
    line = _error_line(result)
    assert setting.partition("=")[0].rpartition(".")[2] in line
    assert not (tmp_path / "x.png").exists()


def test_error_out_is_directory(tmp_path: Path, run_cli: CliRunner) -> None:
    folder = tmp_path / "a_folder"
    folder.mkdir()
    line = _run_fail(run_cli, tmp_path, "--map", SMALL_MAP, "--out", str(folder))
    assert str(folder) in line
    assert folder.is_dir() and not any(folder.iterdir())


def test_error_out_in_missing_folder(tmp_path: Path, run_cli: CliRunner) -> None:
    out = tmp_path / "no_such_folder" / "ep.png"
    line = _run_fail(run_cli, tmp_path, "--map", SMALL_MAP, "--out", str(out))
    assert "no_such_folder" in line
    assert not out.parent.exists()


def test_failed_run_keeps_existing_output(tmp_path: Path, run_cli: CliRunner) -> None:
    out = tmp_path / "out.png"
    original = b"known bytes, not a picture \x00\x01\x02"
    out.write_bytes(original)
    result = run_cli("run", "--map", str(tmp_path / "missing.png"), "--max-steps", "5", "--out", str(out))
    _error_line(result)
    assert out.read_bytes() == original
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]


# ---------------------------------------------------------------------------------- one CLI style


def _usage_error(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    """An argparse error of ``main`` in this process: exit status 2, the usage, one error line, nothing on
    stdout; returns the message after ``areasearch: error: ``."""
    from areasearch.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(list(args))
    out, err = capsys.readouterr()
    assert exit_.value.code == 2 and out == "" and "Traceback" not in err, err
    lines = err.splitlines()
    prefix = "areasearch: error: "
    assert lines[0].startswith(f"usage: areasearch {args[0]}") and lines[-1].startswith(prefix), err
    assert sum(line.startswith(ERROR_PREFIXES) for line in lines) == 1, err
    return lines[-1].removeprefix(prefix)


def test_run_takes_max_steps(episodes: tuple[Episode, Episode], capsys: pytest.CaptureFixture[str]) -> None:
    (summary, _), _ = episodes  # played with --max-steps 50
    assert summary["steps"] == 50 and summary["decisions"] == 2  # at steps 0 and 40
    from areasearch.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["run", "--steps", "50"])
    assert exit_.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1] == "areasearch: error: unrecognized arguments: --steps 50"


def _episode_commands(tmp_path: Path) -> dict[str, list[str]]:
    """The commands that play episodes, with arguments that get past the parser."""
    return {
        "run": ["run", "--map", SMALL_MAP, "--out", str(tmp_path / "x.png")],
        "render": ["render", "--method", "greedy", "--map", SMALL_MAP, "--out", str(tmp_path / "x.gif")],
        "eval": ["eval", "--methods", "greedy", "--maps", SMALL_MAP, "--out", str(tmp_path / "results")],
    }


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--robots", "9", "argument --robots: at most 8 robots, got 9"),
        ("--robots", "0", "argument --robots: expected a positive integer, got 0"),
        ("--robots", "three", "argument --robots: expected a positive integer, got 'three'"),
        ("--max-steps", "0", "argument --max-steps: expected a positive integer, got 0"),
        ("--seed", "-1", "argument --seed: expected a non-negative integer seed, got -1"),
    ],
)
def test_run_render_and_eval_refuse_a_bad_count_identically(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], option: str, value: str, message: str
) -> None:
    for command, args in _episode_commands(tmp_path).items():
        values = ["2", value] if command == "eval" and option == "--robots" else [value]  # eval: several sizes
        assert _usage_error(capsys, *args, option, *values) == message, command
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["eval", "--methods", "greedy", "--out", "r", "--episodes", "0"], "argument --episodes: expected a positive"),
        (["eval", "--methods", "greedy", "--out", "r", "--workers", "0"], "argument --workers: expected a positive"),
        (["eval", "--methods", "greedy", "--out", "r", "--maps-per-size", "0"], "argument --maps-per-size: expected"),
        (["render", "--method", "greedy", "--every", "0"], "argument --every: expected a positive integer"),
        (
            ["assign", "--map", "m.yaml", "--robots", "r.json", "--seed", "-2"],
            "argument --seed: expected a non-negative",
        ),
        (
            ["train", "--config", "c.toml", "--out", "o", "--workers", "-1"],
            "argument --workers: expected a non-negative",
        ),
        (
            ["train", "--config", "c.toml", "--out", "o", "--iterations", "0"],
            "argument --iterations: expected a positive",
        ),
    ],
)
def test_other_counts_are_checked_by_the_parser(
    capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    assert _usage_error(capsys, *args).startswith(message)


@pytest.fixture
def set_commands(tmp_path: Path, examples: Path, tiny_training: Path) -> dict[str, list[str]]:
    """Every command that builds a world, with arguments that work."""
    return {
        **_episode_commands(tmp_path),
        "assign": ["assign", "--map", str(examples / "partial_map.yaml"), "--robots", str(examples / "robots.json")],
        "train": ["train", "--config", str(tiny_training), "--out", str(tmp_path / "run"), "--workers", "0"],
    }


@pytest.mark.parametrize("command", ["run", "render", "eval", "assign", "train"])
@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ("robot.radius_m", "--set 'robot.radius_m': expected KEY=VALUE"),
        ("=0.2", "--set '=0.2': expected KEY=VALUE"),
        ("robot.radius_m=nan", "--set 'robot.radius_m=nan': robot.radius_m must be a finite number"),
        ("robot.radius_m=-inf", "--set 'robot.radius_m=-inf': robot.radius_m must be a finite number"),
        ("robot.wheels=4", "unknown setting"),
    ],
)
def test_a_bad_set_is_one_clear_line_on_every_command(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    command: str,
    setting: str,
    message: str,
    set_commands: dict[str, list[str]],
) -> None:
    result = _main_inprocess(capsys, *set_commands[command], "--set", setting)
    line = _error_line(result)
    assert message in line
    if message == "unknown setting":  # the key named, with the keys known there
        expect = "robot.wheels" if command == "train" else "'robot.wheels'; known settings: robot.radius_m"
        assert expect in line, line
    assert result.stdout == "" and not any(tmp_path.iterdir())


def test_run_set_takes_effect(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], episodes: tuple[Episode, Episode]
) -> None:
    (default, _), _ = episodes  # the same episode (map, seed, 50 steps) without --set
    args = ["run", "--map", SMALL_MAP, "--max-steps", "50", "--seed", "1", "--out", str(tmp_path / "ep.png")]
    result = _main_inprocess(capsys, *args, "--set", "targets.count=1", "--set", "decisions.period_steps=25")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["settings"] == {"decisions.period_steps": 25, "world.targets.count": 1}
    assert "settings" not in default
    assert default["decisions"] == 2 and summary["decisions"] == 2  # steps 0 and 40; 0 and 25
    discovered = default["discovered"]
    assert isinstance(discovered, int) and discovered > 1 and summary["discovered"] <= 1  # one target only


def test_render_set_takes_effect(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["--map", SMALL_MAP, "--robots", "2", "--max-steps", "40", "--every", "20"]
    changed = ["--set", "decisions.period_steps=20", "--set", "world.targets.count=3"]
    result = _main_inprocess(capsys, "render", "--method", "greedy", *args, *changed, "--out", str(tmp_path / "a.gif"))
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["settings"] == {"decisions.period_steps": 20, "world.targets.count": 3}
    assert summary["decisions"] == 2 and summary["frames"] == 3  # a decision every 20 steps, not 40
    out = tmp_path / "b.gif"
    result = _main_inprocess(capsys, "render", "--methods", "greedy", "random", *args, *changed, "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert "decisions.period_steps=20, targets.count=3" in out.with_suffix(".md").read_text().splitlines()[0]
    assert [row["decisions"] for row in json.loads(result.stdout.split("\n\n", 1)[1])["methods"]] == [2, 2]


def _goals(result: subprocess.CompletedProcess[str]) -> list[tuple[float, float] | None]:
    assert result.returncode == 0, result.stderr
    return [tuple(robot["goal"]) if robot["goal"] else None for robot in json.loads(result.stdout)["robots"]]


def test_assign_reads_the_robots_from_standard_input(tmp_path: Path, run_cli: CliRunner, examples: Path) -> None:
    args = ["assign", "--map", str(examples / "partial_map.yaml")]
    from_file = run_cli(*args, "--robots", str(examples / "robots.json"))
    piped = run_cli(*args, "--robots", "-", input=(examples / "robots.json").read_text())
    assert piped.returncode == 0 and piped.stderr == "", piped.stderr
    assert piped.stdout == from_file.stdout
    # the checks of a file: its size limit, valid JSON, the robots' fields; each one clear line
    for text, env, message in (
        ("{" * 80, {"AREASEARCH_MAX_JSON_BYTES": "64"}, "standard input: the robots JSON is larger than 64 bytes"),
        ("{", {}, "standard input: not valid JSON"),
        ('{"robots": [{"x": 0}]}', {}, "standard input: robots[0] has no 'y'"),
    ):
        bad = run_cli(*args, "--robots", "-", input=text, env=env)
        assert bad.returncode == 2 and message in _error_line(bad), bad.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "--no-such-option"], "unrecognized arguments: --no-such-option"),
        (["maps", "--json", "extra"], "unrecognized arguments: extra"),
        (["render", "--method", "greedy", "--fps"], "argument --fps: expected one argument"),
        (["eval", "--methods", "greedy"], "the following arguments are required: --out"),
        (["assign", "--map", "m.yaml"], "the following arguments are required: --robots"),
        (["train", "--config", "c.toml", "--out", "o", "--device", "tpu"], "argument --device: invalid choice"),
        (["serve", "--port", "x"], "argument --port: expected a non-negative integer"),
    ],
)
def test_a_malformed_command_line_ends_in_one_areasearch_error_line(
    args: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """As the README says: the command's usage, then one ``areasearch: error: ...`` line, exit status 2."""
    assert _usage_error(capsys, *args).startswith(message)


def test_json_numbers_are_rounded_to_what_they_mean(episodes: tuple[Episode, Episode]) -> None:
    (summary, _), _ = episodes
    for key, value in summary.items():
        for number in value if isinstance(value, list) else [value]:
            if isinstance(number, float):
                decimals = len(repr(number).partition(".")[2])
                assert decimals <= (2 if key.endswith(("_pct", "_m2")) else 3), (key, number)


def test_assign_set_takes_effect(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], set_commands: dict[str, list[str]]
) -> None:
    args = set_commands["assign"]
    default = _goals(_main_inprocess(capsys, *args))
    single = _goals(_main_inprocess(capsys, *args, "--set", "candidates.max_candidates=1"))
    assert len(set(default)) == len(default) > 1  # the robots go different ways
    assert len({goal for goal in single if goal is not None}) == 1  # one candidate offered: one goal for all
    radius = _main_inprocess(capsys, *args, "--radius-m", "0.2", "--set", "robot.radius_m=0.2")
    assert "--set robot.radius_m=... is not allowed here; use --radius-m" in _error_line(radius)


@pytest.mark.slow
def test_train_set_takes_effect_and_progress_is_plain_off_a_terminal(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], set_commands: dict[str, list[str]]
) -> None:
    args = set_commands["train"]
    result = _main_inprocess(capsys, *args, "--set", "total_decisions=2", "--set", "rollout.episodes=1")
    assert result.returncode == 0, result.stderr
    saved = json.loads((tmp_path / "run" / "config.json").read_text())
    assert saved["total_decisions"] == 2 and saved["rollout"]["episodes"] == 1  # good.toml: 4 and 2
    assert result.stdout.startswith("iter    1  decisions       2/2  ")  # one episode of 80 steps: 2 decisions
    assert "\r" not in result.stderr  # stderr is no terminal here: plain lines
    assert result.stderr.splitlines()[-1].startswith("train: 2/2 decisions  ")


# ---------------------------------------------------------------------------------- eval --set and progress

EVAL = ("eval", "--methods", "greedy", "--maps", SMALL_MAP, "--robots", "2", "--episodes", "1", "--max-steps", "40")


@pytest.fixture(scope="module")
def eval_run(
    tmp_path_factory: pytest.TempPathFactory, run_cli: CliRunner
) -> tuple[Path, subprocess.CompletedProcess[str]]:
    """``areasearch eval --set decisions.period_steps=20`` (one short episode), stderr to a pipe."""
    out = tmp_path_factory.mktemp("eval") / "run"
    return out, run_cli(*EVAL, "--set", "decisions.period_steps=20", "--out", str(out))


@pytest.mark.slow
def test_eval_set_reaches_the_episodes_and_config_json(eval_run: tuple[Path, subprocess.CompletedProcess[str]]) -> None:
    out, result = eval_run
    assert result.returncode == 0, result.stderr
    config = json.loads((out / "config.json").read_text())
    assert config["settings"] == {"decisions.period_steps": 20}
    assert config["config"]["decisions"]["period_steps"] == 20
    rows = (out / "episodes.csv").read_text().splitlines()
    assert len(rows) == 2 and rows[1].split(",")[-2] == "2"  # decisions: a decision every 20 of 40 steps
    assert "decisions.period_steps=20" in (out / "summary.md").read_text()


@pytest.mark.slow
def test_eval_progress_off_a_terminal_is_plain_lines(eval_run: tuple[Path, subprocess.CompletedProcess[str]]) -> None:
    _, result = eval_run
    assert "\r" not in result.stderr
    lines = result.stderr.splitlines()
    assert lines and all(line.startswith("eval: ") for line in lines), result.stderr
    assert lines[-1].startswith("eval: 1/1 episodes  ") and lines[-1].endswith("(100 %)")


@pytest.mark.slow
def test_eval_refuses_to_resume_with_other_settings(
    eval_run: tuple[Path, subprocess.CompletedProcess[str]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    shutil.copytree(eval_run[0], out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    for changed in (["--set", "decisions.period_steps=10"], [], ["--set", "targets.count=5"]):
        line = _error_line(_main_inprocess(capsys, *EVAL, *changed, "--out", str(out)))
        assert f"{out}: holds episodes of a run with other settings (settings, config differ)" in line
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    # the same settings, in another key form: resumed, nothing played again
    result = _main_inprocess(capsys, *EVAL, "--set", "decisions__period_steps=20", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert (out / "episodes.csv").read_bytes() == before["episodes.csv"]
    assert result.stderr == ""  # nothing to play: no progress report


@pytest.mark.slow
def test_eval_progress_on_a_terminal_is_one_self_overwriting_line(tmp_path: Path) -> None:
    import pty
    import select

    leader, follower = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "areasearch.cli", *EVAL, "--out", str(tmp_path / "run")],
        stdout=subprocess.DEVNULL,
        stderr=follower,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    os.close(follower)
    seen = b""
    try:
        while True:
            ready, _, _ = select.select([leader], [], [], 120)
            if not ready:
                break
            try:
                chunk = os.read(leader, 4096)
            except OSError:  # the process closed the terminal
                break
            if not chunk:
                break
            seen += chunk
    finally:
        proc.wait(timeout=120)
        os.close(leader)
    assert proc.returncode == 0, seen
    text = seen.decode()
    frames = text.split("\reval [")
    assert len(frames) >= 3, text  # the start, the episode done, the end
    assert frames[1].startswith("........................] 0/1 episodes")
    assert frames[-1].startswith("########################] 1/1 episodes") and text.endswith("\n")
    assert text.count("\n") == 1  # one line in all (the terminal turns it into \r\n)
