"""Tests of ``areasearch render`` (:mod:`areasearch.harness.animate`): a valid animated GIF and a PNG, the
episode of an ``episodes.csv`` seed replayed exactly, clear errors for outputs it cannot write."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageSequence

from areasearch.harness.animate import render_episode
from areasearch.harness.evaluate import EvalPlan, evaluate, read_episodes

CliRunner = Callable[..., subprocess.CompletedProcess[str]]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_render_writes_an_animated_gif_and_the_last_frame(tmp_path: Path, run_cli: CliRunner, small_map: str) -> None:
    out = tmp_path / "episode.gif"
    result = run_cli(
        "render", "--method", "greedy", "--map", small_map, "--robots", "3", "--seed", "4",
        "--max-steps", "200", "--every", "20", "--out", str(out),
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["method"] == "greedy" and summary["map"] == small_map and summary["robots"] == 3
    assert summary["steps"] == 200 and summary["decisions"] == 5
    assert summary["frames"] == 11  # step 0, then every 20 steps
    with Image.open(out) as gif:
        assert gif.format == "GIF"
        frames = [np.asarray(frame.convert("RGB")) for frame in ImageSequence.Iterator(gif)]
    assert len(frames) == 11
    assert not np.array_equal(frames[0], frames[-1])  # the robots moved and mapped
    size = frames[0].shape[1], frames[0].shape[0]
    picture = tmp_path / "episode.png"
    assert summary["picture"] == str(picture)
    assert picture.read_bytes()[:8] == PNG_SIGNATURE
    with Image.open(picture) as png:
        assert png.size[0] == size[0] and png.size[1] < size[1]  # the GIF frames carry a caption band
    assert sorted(p.name for p in tmp_path.iterdir()) == ["episode.gif", "episode.png"]


def test_render_replays_an_evaluated_episode_from_its_seed(tmp_path: Path, small_map: str) -> None:
    evaluate(EvalPlan(["random"], [2], [small_map], 1, 11, 200, tmp_path / "run"), progress=None)
    (row,) = read_episodes(tmp_path / "run" / "episodes.csv")
    replay = render_episode("random", small_map, 2, row["seed"], tmp_path / "replay.gif", max_steps=200)
    for key in ("explored_pct", "covered_pct", "time_e", "time_c", "collisions", "path_length_m", "decisions"):
        assert replay[key] == row[key], key


def test_render_mp4_without_ffmpeg_is_a_clear_error(tmp_path: Path, run_cli: CliRunner, small_map: str) -> None:
    empty = tmp_path / "bin"
    empty.mkdir()
    out = tmp_path / "episode.mp4"
    result = run_cli("render", "--method", "greedy", "--map", small_map, "--out", str(out), env={"PATH": str(empty)})
    assert result.returncode == 2
    assert result.stderr.splitlines() == [
        f"areasearch: error: {out}: writing .mp4 needs ffmpeg on PATH; install ffmpeg or write a .gif"
    ]
    assert not out.exists()


def test_render_bad_input_leaves_an_existing_animation_alone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], small_map: str
) -> None:
    from areasearch.cli import main  # in this process: an exception escaping main would be a traceback

    out = tmp_path / "episode.gif"
    out.write_bytes(b"old animation")
    for args, message in (
        (["--map", small_map, "--method", "teleport"], "unknown planner 'teleport'"),
        (["--map", "no_such_map", "--method", "greedy"], "no_such_map: not a bundled map id"),
        (["--map", small_map, "--method", "greedy", "--set", "robot.wheels=4"], "unknown setting 'robot.wheels'"),
    ):
        code = main(["render", *args, "--max-steps", "200", "--out", str(out)])
        captured = capsys.readouterr()
        assert code == 2, captured.err
        lines = captured.err.splitlines()
        assert len(lines) == 1 and lines[0].startswith("areasearch: error: ") and message in lines[0], lines
        assert captured.out == ""
    for args, message in (
        (["--method", "greedy", "--robots", "9"], "argument --robots: at most 8 robots, got 9"),
        (["--method", "greedy", "--every", "0"], "argument --every: expected a positive integer, got 0"),
    ):
        with pytest.raises(SystemExit) as exit_:  # a malformed option: argparse's usage line and error
            main(["render", "--map", small_map, *args, "--max-steps", "200", "--out", str(out)])
        captured = capsys.readouterr()
        assert exit_.value.code == 2
        assert captured.err.splitlines()[-1] == f"areasearch: error: {message}", captured.err
        assert captured.out == ""
    assert out.read_bytes() == b"old animation"
    assert main(["render", "--method", "greedy", "--map", small_map, "--out", str(tmp_path / "episode.png")]) == 2
    assert "must be a .gif or .mp4" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["episode.gif"]


@pytest.mark.slow
def test_render_methods_side_by_side_with_table(tmp_path: Path, run_cli: CliRunner) -> None:
    out = tmp_path / "cmp.gif"
    res = run_cli(
        "render", "--methods", "greedy", "random", "--map", "wrs2020_arena",
        "--robots", "2", "--seed", "1", "--max-steps", "120", "--out", str(out), timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    table = out.with_suffix(".md").read_text()
    assert "| greedy |" in table and "| random |" in table
    both = np.asarray(Image.open(tmp_path / "cmp.png").convert("RGB"))
    half = (both.shape[1] - 6) // 2  # two panels of one map, 6 white pixels apart
    assert out.exists() and (both.shape[1] - 6) % 2 == 0
    assert (
        (both[:, half : half + 6] == 255).all() and (both[:, :half] != 255).any() and (both[:, half + 6 :] != 255).any()
    )
    bad = run_cli("render", "--methods", "greedy", "nosuch", "--out", str(tmp_path / "x.gif"))
    assert bad.returncode == 2 and "unknown planner" in bad.stderr and not (tmp_path / "x.gif").exists()
