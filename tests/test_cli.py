"""Tests of the ``areasearch`` command line, run in a subprocess as a user would."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from areasearch.scene import bundled_index

ERROR_PREFIXES = ("areasearch: error:", "areasearch run: error:", "areasearch maps: error:")
_SMALL_BY_AREA = sorted((e for e in bundled_index() if e["size_class"] == "small"), key=lambda e: e["free_area_m2"])
SMALL_MAP = _SMALL_BY_AREA[0]["id"]
LARGEST_SMALL_MAP = _SMALL_BY_AREA[-1]["id"]
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.run(
        [sys.executable, "-m", "areasearch.cli", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=120,
        check=False,
    )


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


def test_main_guard_present() -> None:
    source = Path(__file__).resolve().parents[1] / "src" / "areasearch" / "cli.py"
    assert 'if __name__ == "__main__":' in source.read_text()


def test_help_lists_subcommands() -> None:
    result = _cli("--help")
    assert result.returncode == 0, result.stderr
    assert "run" in result.stdout.split()
    assert "maps" in result.stdout.split()


def test_no_subcommand_is_an_error() -> None:
    result = _cli()
    _error_line(result, argparse_error=True)


def test_maps_lists_every_bundled_map() -> None:
    result = _cli("maps")
    assert result.returncode == 0, result.stderr
    rows = {line.split()[0]: line.split()[1] for line in result.stdout.splitlines()[1:-1]}
    index = bundled_index()
    assert rows == {e["id"]: e["size_class"] for e in index}
    assert f"{len(index)} maps" in result.stdout.splitlines()[-1]


def test_maps_size_filter() -> None:
    result = _cli("maps", "--size", "small")
    assert result.returncode == 0, result.stderr
    rows = [line.split() for line in result.stdout.splitlines()[1:-1]]
    expected = sorted(e["id"] for e in bundled_index() if e["size_class"] == "small")
    assert sorted(row[0] for row in rows) == expected
    assert {row[1] for row in rows} == {"small"}


def test_maps_json() -> None:
    result = _cli("maps", "--json", "--size", "medium", "large")
    assert result.returncode == 0, result.stderr
    entries = json.loads(result.stdout)
    assert isinstance(entries, list)
    assert entries == [e for e in bundled_index() if e["size_class"] in ("medium", "large")]
    assert all(e["license"] and e["source_repo"] for e in entries)


# ---------------------------------------------------------------------------------- run


def _run_episode(tmp: Path, name: str) -> tuple[dict[str, object], bytes]:
    out = tmp / name
    result = _cli("run", "--map", SMALL_MAP, "--steps", "50", "--seed", "1", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    summary = json.loads(result.stdout)
    assert summary["picture"] == str(out)
    return summary, out.read_bytes()


Episode = tuple[dict[str, object], bytes]


@pytest.fixture(scope="module")
def episodes(tmp_path_factory: pytest.TempPathFactory) -> tuple[Episode, Episode]:
    """The same run twice (seed 1), into two files of one folder."""
    tmp = tmp_path_factory.mktemp("episodes")
    return _run_episode(tmp, "ep.png"), _run_episode(tmp, "ep2.png")


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


def _run_fail(tmp_path: Path, *args: str, argparse_error: bool = False) -> str:
    """Run ``areasearch run`` expecting a clean failure; unless ``--out`` is given, check nothing was written."""
    default_out = tmp_path / "ep.png"
    own_out = "--out" in args
    if not own_out:
        args = (*args, "--out", str(default_out))
    result = _cli("run", "--steps", "5", *args)
    line = _error_line(result, argparse_error=argparse_error)
    if not own_out:
        assert not default_out.exists()
    return line


def test_error_missing_map_file(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere" / "lost_map.png"
    line = _run_fail(tmp_path, "--map", str(missing))
    assert str(missing) in line


def test_error_file_not_an_image(tmp_path: Path) -> None:
    path = _map_folder(tmp_path, "fake.png", text="definitely not a PNG\n")
    line = _run_fail(tmp_path, "--map", str(path))
    assert "fake.png" in line


def test_error_png_without_free_cell(tmp_path: Path) -> None:
    path = _map_folder(tmp_path, "blank.png", pixels=np.zeros((16, 16), dtype=np.uint8))
    line = _run_fail(tmp_path, "--map", str(path))
    assert "blank" in line
    assert "free" in line


def test_error_ros_yaml_missing_key(tmp_path: Path) -> None:
    pixels = np.zeros((20, 20), dtype=np.uint8)
    pixels[2:18, 2:18] = 254
    Image.fromarray(pixels).save(tmp_path / "floor.pgm")
    yaml_path = tmp_path / "floor.yaml"
    data = {"image": "floor.pgm", "resolution": 0.05, "origin": [0, 0, 0], "negate": 0, "free_thresh": 0.196}
    yaml_path.write_text(yaml.safe_dump(data))
    line = _run_fail(tmp_path, "--map", str(yaml_path))
    assert "occupied_thresh" in line
    assert "floor.yaml" in line


def test_error_ros_yaml_syntax_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    yaml_path = tmp_path / "broken.yaml"
    yaml_path.write_text("image: [floor.pgm\nresolution: 0.05\n")
    out = str(tmp_path / "x.png")
    result = _main_inprocess(capsys, "run", "--map", str(yaml_path), "--steps", "5", "--out", out)
    line = _error_line(result)
    assert "broken.yaml" in line


@pytest.mark.parametrize("map_id", [SMALL_MAP, LARGEST_SMALL_MAP])
def test_error_too_many_robots(tmp_path: Path, map_id: str) -> None:
    line = _run_fail(tmp_path, "--map", map_id, "--robots", "8", "--set", "robot.radius_m=1.0")
    assert map_id in line
    assert "radius 1.0" in line


def test_error_negative_radius(tmp_path: Path) -> None:
    line = _run_fail(tmp_path, "--map", SMALL_MAP, "--set", "robot.radius_m=-0.1")
    assert "robot.radius_m" in line


@pytest.mark.parametrize(
    ("args", "field"),
    [(("--robots", "0"), "--robots"), (("--robots", "9"), "--robots"), (("--steps", "0"), "--steps")],
)
def test_error_bad_counts(tmp_path: Path, args: tuple[str, str], field: str) -> None:
    line = _run_fail(tmp_path, "--map", SMALL_MAP, *args, argparse_error=True)
    assert field in line


def test_error_unknown_set_key(tmp_path: Path) -> None:
    line = _run_fail(tmp_path, "--map", SMALL_MAP, "--set", "robot.wheels=3")
    assert "wheels" in line


def test_error_set_without_equals(tmp_path: Path) -> None:
    line = _run_fail(tmp_path, "--map", SMALL_MAP, "--set", "robot.radius_m")
    assert "--set" in line


# The cases below are extra findings; they call main() in-process (an exception escaping main() is the
# traceback a user would see) to keep the subprocess count, and so the runtime, down.


@pytest.mark.parametrize("setting", ["num_robots=9", "max_steps=0"])
def test_error_set_duplicates_option(tmp_path: Path, capsys: pytest.CaptureFixture[str], setting: str) -> None:
    out = str(tmp_path / "x.png")
    result = _main_inprocess(capsys, "run", "--map", SMALL_MAP, "--steps", "5", "--set", setting, "--out", out)
    line = _error_line(result)
    assert setting.partition("=")[0] in line


@pytest.mark.parametrize(
    "setting",
    ["robot=1", "camera=null", "success_fraction=abc", "camera.hfov_deg=abc", "reward.explore_per_m2=abc",
     "targets.count=true"],
)  # fmt: skip
def test_error_set_wrong_type(tmp_path: Path, capsys: pytest.CaptureFixture[str], setting: str) -> None:
    out = str(tmp_path / "x.png")
    result = _main_inprocess(capsys, "run", "--map", SMALL_MAP, "--steps", "5", "--set", setting, "--out", out)
    line = _error_line(result)
    assert setting.partition("=")[0].rpartition(".")[2] in line
    assert not (tmp_path / "x.png").exists()


def test_error_out_is_directory(tmp_path: Path) -> None:
    folder = tmp_path / "a_folder"
    folder.mkdir()
    line = _run_fail(tmp_path, "--map", SMALL_MAP, "--out", str(folder))
    assert str(folder) in line
    assert folder.is_dir() and not any(folder.iterdir())


def test_error_out_in_missing_folder(tmp_path: Path) -> None:
    out = tmp_path / "no_such_folder" / "ep.png"
    line = _run_fail(tmp_path, "--map", SMALL_MAP, "--out", str(out))
    assert "no_such_folder" in line
    assert not out.parent.exists()


def test_failed_run_keeps_existing_output(tmp_path: Path) -> None:
    out = tmp_path / "out.png"
    original = b"known bytes, not a picture \x00\x01\x02"
    out.write_bytes(original)
    result = _cli("run", "--map", str(tmp_path / "missing.png"), "--steps", "5", "--out", str(out))
    _error_line(result)
    assert out.read_bytes() == original
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]
