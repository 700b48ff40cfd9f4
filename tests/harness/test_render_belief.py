"""``areasearch render --belief``: every frame shows the truth beside the team's (or one robot's) believed
map (:func:`areasearch.harness.animate.belief_frame`, :func:`areasearch.sim.render.draw_belief`)."""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageSequence

from areasearch.errors import ConfigError
from areasearch.harness.animate import CAPTION_PX, check_belief, render_episode
from areasearch.harness.evaluate import make_env
from areasearch.sim.render import draw_belief, draw_world

CliRunner = Callable[..., subprocess.CompletedProcess[str]]

NOISE = {"noise.odometry_forward": 0.05, "noise.odometry_turn": 0.05}


def test_render_with_belief_draws_the_truth_beside_the_belief(tmp_path: Path, small_map: str) -> None:
    out = tmp_path / "belief.gif"
    summary = render_episode("greedy", small_map, 2, 3, out, max_steps=80, every=40, settings=NOISE, belief="team")
    assert summary["belief"] == "team" and summary["frames"] == 3 and 0 < summary["map_error_pct"] < 100
    with Image.open(out) as gif:
        frames = [np.asarray(frame.convert("RGB")) for frame in ImageSequence.Iterator(gif)]
    assert len(frames) == 3
    picture = np.asarray(Image.open(tmp_path / "belief.png").convert("RGB"))
    width = picture.shape[1]
    half = (width - 6) // 2  # the truth and the belief, 6 white pixels apart
    assert (width - 6) % 2 == 0 and frames[0].shape[1] == width and frames[0].shape[0] == picture.shape[0] + CAPTION_PX
    assert (picture[:, half : half + 6] == 255).all()
    assert not np.array_equal(picture[:, :half], picture[:, half + 6 :])  # the noisy map differs from the truth


def test_a_robot_belief_under_limited_communication(small_map: str) -> None:
    from areasearch.config import search_config

    settings = {"world.comm.model": "disc", "world.comm.range_m": 0.5, **{f"world.{k}": v for k, v in NOISE.items()}}
    config = search_config(settings)
    env = make_env(small_map, 2, 3, 60, config)
    env.reset(seed=3)
    for _ in range(60):
        env.world.step(np.zeros(2, dtype=np.int64))
    world = env.world
    team, robot0, robot1 = draw_belief(world), draw_belief(world, 0), draw_belief(world, 1)
    assert team.shape == robot0.shape == draw_world(world).shape == draw_world(world, truth=True).shape
    assert not np.array_equal(robot0, robot1)  # apart, each robot holds its own map


def test_check_belief_names_the_option() -> None:
    assert check_belief("team", 3) is None and check_belief("2", 3) == 2
    for bad in ("3", "-1", "all", ""):
        with pytest.raises(ConfigError, match="--belief must be 'team' or a robot from 0 to 2"):
            check_belief(bad, 3)


def test_render_cli_belief_bad_value_is_one_error_line(tmp_path: Path, run_cli: CliRunner, small_map: str) -> None:
    out = tmp_path / "x.gif"
    res = run_cli("render", "--method", "greedy", "--map", small_map, "--belief", "robot7", "--out", str(out))
    assert res.returncode == 2 and not out.exists()
    assert res.stderr.splitlines() == [
        "areasearch: error: --belief must be 'team' or a robot from 0 to 2, got 'robot7'"
    ]
