"""``--realism none|low|medium|high`` on ``run``, ``render``, ``eval`` and ``train``: the preset reaches
the world, an explicit ``--set`` wins over it, an unknown name is one error line, ``eval`` records it in
``config.json`` (only when not ``none``) and refuses to resume a folder under another preset, and a
training run records it and refuses a resume under another."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from areasearch.cli.options import EPISODE_OPTIONS, world_options
from areasearch.config import SearchConfig

SMALL_MAP = "bormann_lab_c_rooms1"
EVAL = ("eval", "--methods", "greedy", "--maps", SMALL_MAP, "--robots", "2", "--episodes", "1", "--max-steps", "40")


def _main(capsys: pytest.CaptureFixture[str], *args: str) -> subprocess.CompletedProcess[str]:
    """``areasearch.cli.main`` in this process: exit status, stdout, stderr."""
    from areasearch.cli import main

    code = main(list(args))
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(list(args), code, out, err)


def _one_error(result: subprocess.CompletedProcess[str]) -> str:
    """The one line of stderr of a refused command (exit status 2, nothing else said)."""
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("areasearch: error: "), result.stderr
    return lines[0]


@pytest.mark.parametrize(
    "args",
    [
        ["run", "--out", "x.png"],
        ["render", "--method", "greedy"],
        ["eval", "--methods", "greedy", "--out", "r"],
        ["train", "--config", "c.toml", "--out", "o"],
    ],
)
def test_an_unknown_preset_is_one_error_line_naming_the_presets(
    args: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    from areasearch.cli import main

    with pytest.raises(SystemExit) as exit_:
        main([*args, "--realism", "extreme"])
    out, err = capsys.readouterr()
    assert exit_.value.code == 2 and out == "" and "Traceback" not in err
    errors = [line for line in err.splitlines() if line.startswith("areasearch: error: ")]
    assert errors == [err.splitlines()[-1]] and err.startswith(f"usage: areasearch {args[0]}")
    assert errors[0] == (
        "areasearch: error: argument --realism: invalid choice: 'extreme' (choose from 'none', 'low', 'medium', 'high')"
    )


def test_world_options_apply_the_preset_under_the_settings() -> None:
    world = world_options(["noise.forward=0.2", "comm.model=disc"], EPISODE_OPTIONS, "passby", "medium")
    assert world.realism == "medium" and world.given == {
        "world.comm.model": "disc",
        "world.noise.forward": 0.2,
        "world.protocol": "passby",
    }
    config = world.config()
    assert config.world.noise.forward == 0.2 and config.world.noise.turn == 0.05  # --set wins, the rest the preset's
    assert config.world.comm.model == "disc" and config.world.detection.model == "linear"
    assert config.world.protocol == "passby"
    assert world.applied["world.noise.dropout"] == 0.05
    plain = world_options(None, EPISODE_OPTIONS)
    assert plain.realism == "none" and plain.config() == SearchConfig() and plain.applied == {}
    assert world_options(None, EPISODE_OPTIONS, None, "none").config() == SearchConfig()


def test_run_none_is_the_default_run_and_a_preset_is_echoed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["run", "--map", SMALL_MAP, "--max-steps", "50", "--seed", "2"]
    plain = _main(capsys, *args, "--out", str(tmp_path / "a.png"))
    none = _main(capsys, *args, "--out", str(tmp_path / "b.png"), "--realism", "none")
    assert plain.returncode == none.returncode == 0, plain.stderr + none.stderr
    assert none.stdout == plain.stdout.replace("a.png", "b.png")
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    high = _main(capsys, *args, "--out", str(tmp_path / "c.png"), "--realism", "high", "--set", "noise.dropout=0")
    assert high.returncode == 0, high.stderr
    summary = json.loads(high.stdout)
    assert summary["realism"] == "high" and summary["settings"] == {"world.noise.dropout": 0.0}
    assert "realism" not in json.loads(plain.stdout)


def test_render_plays_the_preset(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "ep.gif"
    args = ["render", "--method", "greedy", "--map", SMALL_MAP, "--max-steps", "40", "--out", str(out)]
    result = _main(capsys, *args, "--realism", "low", "--set", "comm.range_m=5")
    assert result.returncode == 0, result.stderr
    settings = json.loads(result.stdout)["settings"]
    assert settings["world.comm.range_m"] == 5.0 and settings["world.comm.model"] == "disc"  # --set wins
    assert settings["world.noise.forward"] == 0.025 and settings["world.detection.model"] == "constant"


@pytest.fixture(scope="module")
def medium_eval(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A results folder of ``eval --realism medium --set noise.forward=0.2`` (one episode of 40 steps)."""
    from areasearch.cli import main

    out = tmp_path_factory.mktemp("realism") / "medium"
    assert main([*EVAL, "--realism", "medium", "--set", "noise.forward=0.2", "--out", str(out)]) == 0
    return out


def test_eval_records_the_preset_and_its_world(medium_eval: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    record = json.loads((medium_eval / "config.json").read_text())
    assert record["realism"] == "medium" and record["settings"] == {"world.noise.forward": 0.2}
    world = record["config"]["world"]
    assert world["noise"]["forward"] == 0.2 and world["noise"]["turn"] == 0.05  # --set wins over the preset
    assert world["detection"] == {"model": "linear", "p_near": 0.95, "p_far": 0.6}
    assert world["comm"]["model"] == "signal"
    assert "realism medium" in (medium_eval / "summary.md").read_text()


def test_eval_none_writes_the_default_config_json(
    tmp_path: Path, medium_eval: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plain, none = tmp_path / "plain", tmp_path / "none"
    assert _main(capsys, *EVAL, "--out", str(plain)).returncode == 0
    assert _main(capsys, *EVAL, "--realism", "none", "--out", str(none)).returncode == 0
    for name in ("config.json", "curves.jsonl"):
        assert (none / name).read_bytes() == (plain / name).read_bytes(), name

    def rows(folder: Path) -> list[str]:  # each row less its last column, the wall-clock time
        return [line.rpartition(",")[0] for line in (folder / "episodes.csv").read_text().splitlines()]

    assert rows(none) == rows(plain)
    record = json.loads((plain / "config.json").read_text())
    assert "realism" not in record and not {"noise", "detection", "comm"} & set(record["config"]["world"])


@pytest.mark.parametrize(
    ("changed", "message"),
    [
        (
            ["--realism", "high", "--set", "noise.forward=0.2"],
            "(realism, config differ: realism medium there, high now)",
        ),
        (["--set", "noise.forward=0.2"], "(realism, config differ: realism medium there, none now)"),
        (
            ["--realism", "none", "--set", "noise.forward=0.2"],
            "(realism, config differ: realism medium there, none now)",
        ),
        (["--realism", "medium"], "(settings, config differ)"),
        (["--realism", "medium", "--set", "noise.forward=0.3"], "(settings, config differ)"),
    ],
)
def test_eval_refuses_to_resume_under_another_preset_or_setting(
    medium_eval: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], changed: list[str], message: str
) -> None:
    out = tmp_path / "run"
    shutil.copytree(medium_eval, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    line = _one_error(_main(capsys, *EVAL, *changed, "--out", str(out)))
    assert line == (
        f"areasearch: error: {out}: holds episodes of a run with other settings {message}; use another --out "
        "folder or the same settings"
    )
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    same = _main(capsys, *EVAL, "--set", "noise__forward=0.2", "--realism", "medium", "--out", str(out))
    assert same.returncode == 0 and same.stderr == "", same.stderr  # resumed, nothing to play
    assert (out / "episodes.csv").read_bytes() == before["episodes.csv"]


@pytest.mark.slow
def test_train_records_the_preset_and_refuses_a_resume_under_another(
    tmp_path: Path, tiny_training: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run"
    start = ["train", "--config", str(tiny_training), "--out", str(run), "--workers", "0"]
    small = ["--set", "total_decisions=2", "--set", "rollout.episodes=1"]
    result = _main(capsys, *start, *small, "--realism", "medium", "--set", "rollout.env.noise.forward=0.2")
    assert result.returncode == 0, result.stderr
    assert (
        "realism 'medium': its noise, detection and mapping apply to the training episodes, its communication "
        "(signal) does not" in result.stdout
    ), result.stdout
    env = json.loads((run / "config.json").read_text())["rollout"]["env"]
    assert env == {"protocol": "paper", "realism": "medium", "noise.forward": 0.2}
    resume = ["train", "--out", str(run), "--workers", "0", "--resume"]
    for preset, shown in (("high", "'high'"), ("none", "absent")):  # none: no preset, so none recorded
        line = _one_error(_main(capsys, *resume, "--realism", preset))
        assert f"it differs in rollout.env.realism (run: 'medium', given: {shown}). Resume with" in line, line
    line = _one_error(_main(capsys, *resume, "--set", "rollout.env.noise.forward=0.1"))
    assert "rollout.env.noise.forward (run: 0.2, given: 0.1)" in line, line
    same = _main(capsys, *start, *small, "--resume", "--realism", "medium", "--set", "rollout.env.noise.forward=0.2")
    assert same.returncode == 0, same.stderr  # the run's own config: accepted (already finished)
    assert _main(capsys, *resume, "--realism", "medium").returncode == 0


def test_train_refuses_a_preset_given_twice(
    tmp_path: Path, tiny_training: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["train", "--config", str(tiny_training), "--out", str(tmp_path / "run"), "--realism", "low"]
    line = _one_error(_main(capsys, *args, "--set", "rollout.env.realism=high"))
    assert line == "areasearch: error: give the preset once: --realism or --set rollout.env.realism=..., not both"
    bad = ["train", "--config", str(tiny_training), "--out", str(tmp_path / "r"), "--set", "rollout.env.realism=max"]
    line = _one_error(_main(capsys, *bad))
    assert "rollout.env: realism must be one of 'none', 'low', 'medium', 'high', got 'max'" in line, line
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(
    "settings",
    [
        ["--set", "rollout.env.comm.model=disc"],
        ["--realism", "low", "--set", "rollout.env.comm.range_m=5"],  # a comm setting: the preset's disc kept
    ],
)
def test_train_refuses_limited_communication(
    tmp_path: Path, tiny_training: Path, capsys: pytest.CaptureFixture[str], settings: list[str]
) -> None:
    args = ["train", "--config", str(tiny_training), "--out", str(tmp_path / "run"), *settings]
    line = _one_error(_main(capsys, *args))
    assert "training under limited communication (comm.model 'disc') is not supported" in line, line
    assert not any(tmp_path.iterdir())
