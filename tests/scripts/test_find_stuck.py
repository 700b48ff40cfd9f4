"""scripts/find_stuck.py: the stall step, the stuck criteria, a run end to end, bad input."""

from __future__ import annotations

import csv
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from areasearch.harness.evaluate import read_episodes

ROOT = Path(__file__).resolve().parents[2]  # read at import time: the script is loaded once
SCRIPT = ROOT / "scripts" / "find_stuck.py"
_spec = importlib.util.spec_from_file_location("find_stuck", SCRIPT)
assert _spec is not None and _spec.loader is not None
find_stuck = importlib.util.module_from_spec(_spec)
sys.modules["find_stuck"] = find_stuck  # its dataclasses look their module up there
_spec.loader.exec_module(find_stuck)

STEPS = [0, 40, 80, 120, 160]
SMALL_MAP = "bormann_office_d_rooms2"  # small (16.5 m2): 2 robots explore ~55 % of it in 120 steps
RUN = ["--methods", "greedy", "--robots", "2", "--maps", SMALL_MAP, "--episodes", "1", "--max-steps", "120"]


# ---------------------------------------------------------------------------------- stall step


def test_a_plateau_stalls_from_its_first_step() -> None:
    stall = find_stuck.stall_step(STEPS, [10.0, 50.0, 60.0, 60.0, 60.0], [0.0, 5.0, 10.0, 10.0, 10.0])
    assert (stall.step, stall.stalled, stall.index) == (80, True, 2)


def test_a_late_increase_moves_the_stall_step() -> None:
    # explored flat from step 40, covered rises once more at step 120
    stall = find_stuck.stall_step(STEPS, [10.0, 50.0, 50.0, 50.0, 50.0], [0.0, 5.0, 5.0, 8.0, 8.0])
    assert (stall.step, stall.stalled) == (120, True)
    # an increase at the very last decision: still progressing, the step of that increase
    stall = find_stuck.stall_step(STEPS, [10.0, 50.0, 50.0, 50.0, 70.0], [0.0, 5.0, 5.0, 5.0, 5.0])
    assert (stall.step, stall.stalled) == (160, False)


def test_no_progress_at_all_stalls_from_the_reset() -> None:
    stall = find_stuck.stall_step(STEPS, [12.0] * 5, [0.0] * 5)
    assert (stall.step, stall.stalled, stall.index) == (0, True, 0)


def test_progress_to_the_end_never_stalls() -> None:
    stall = find_stuck.stall_step(STEPS, [10.0, 20.0, 30.0, 40.0, 50.0], [0.0, 1.0, 2.0, 3.0, 4.0])
    assert (stall.step, stall.stalled, stall.index) == (160, False, 4)


def test_increases_within_epsilon_are_no_progress() -> None:
    eps = find_stuck.EPSILON_PCT
    explored = [10.0, 50.0, 50.0 + eps / 3, 50.0 + 2 * eps / 3, 50.0 + eps]
    stall = find_stuck.stall_step(STEPS, explored, [0.0, 5.0, 5.0, 5.0, 5.0])
    assert (stall.step, stall.stalled) == (40, True)


def test_a_curve_of_mismatched_lengths_is_refused() -> None:
    with pytest.raises(ValueError):
        find_stuck.stall_step([0, 40], [1.0], [0.0, 1.0])


# ---------------------------------------------------------------------------------- criteria


def _row(size: str, explored: float, collisions: int = 0, method: str = "greedy", robots: int = 3) -> dict:
    return {"size_class": size, "explored_pct": explored, "collisions": collisions, "method": method, "robots": robots}


def test_a_team_standing_still_to_the_horizon_is_stalled() -> None:
    """Stalled: run to the horizon with no progress during the last ``max_stall`` steps or more; an
    episode that ended before the horizon (it finished) or stalled for less is not."""
    reasons = find_stuck.stuck_reasons
    steps = list(range(0, 3601, 40))
    flat_from = {1200: 2400, 2600: 1000, 2640: 960}  # stall step -> steps without progress
    for stall, without in flat_from.items():
        explored = [min(100.0, s / 12) for s in steps]
        covered = [min(99.0, s / stall * 99.0) for s in steps]
        curve = {"steps": steps, "explored_pct": explored, "covered_pct": covered}
        expected = ["stalled"] if without >= 1000 else []
        assert reasons(_row("small", 100.0), curve=curve, max_steps=3600) == expected, stall
    short = {"steps": steps[:30], "explored_pct": [100.0] * 30, "covered_pct": [50.0] * 30}
    assert reasons(_row("small", 100.0), curve=short, max_steps=3600) == []  # ended early: finished
    assert reasons(_row("small", 100.0), curve=curve, max_steps=3600, max_stall=500) == ["stalled"]


def test_stuck_criteria() -> None:
    reasons = find_stuck.stuck_reasons
    assert reasons(_row("small", 90.0)) == ["explored"]
    assert reasons(_row("medium", 94.99)) == ["explored"]
    assert reasons(_row("large", 90.0)) == []  # large maps are not expected to be explored
    assert reasons(_row("small", 95.0)) == []
    assert reasons(_row("large", 100.0, collisions=1001)) == ["collisions"]
    assert reasons(_row("small", 100.0, collisions=1000)) == []
    assert reasons(_row("medium", 50.0, collisions=5000)) == ["explored", "collisions"]
    # the thresholds are options
    assert reasons(_row("small", 90.0), min_explored=85.0) == []
    assert reasons(_row("small", 100.0, collisions=11), max_collisions=10) == ["collisions"]


def test_markdown_counts_per_method_and_team_and_the_totals() -> None:
    rows = [_row("small", 90.0, robots=r, method=m) for m in ("greedy", "random") for r in (3, 4)]
    stuck = [
        {
            **{"map": "m", "size_class": "small", "method": "random", "robots": 4, "episode": 0, "seed": 1},
            **{"explored_pct": 90.0, "covered_pct": 10.0, "collisions": 1234, "reason": "explored+collisions"},
            **{"stalled_from_step": 80, "stalled": True, "last_step": 3600, "picture": "stuck/x.png"},
            "replay_matches": True,
        }
    ]
    text = find_stuck.to_markdown(stuck, rows)
    assert "| m | small | random | 4 | 0 | 1 | 90.00 | 10.00 | 1,234 | explored+collisions | 80 of 3600 | yes " in text
    assert "[png](stuck/x.png)" in text
    assert "| greedy | 0 / 1 | 0 / 1 | 0 / 2 |" in text
    assert "| random | 0 / 1 | 1 / 1 | 1 / 2 |" in text
    assert text.rstrip().endswith("1 stuck of 4 episodes")
    assert "differs" not in text
    assert "differs from the recorded curve" in find_stuck.to_markdown([{**stuck[0], "replay_matches": False}], rows)
    assert "No stuck episode." in find_stuck.to_markdown([], rows)


# ---------------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("find_stuck") / "run"
    assert find_stuck.main(["--out", str(out), *RUN, "--workers", "1"]) == 0
    return out


@pytest.mark.slow
def test_a_short_horizon_on_a_small_map_is_found_stuck(run_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (row,) = read_episodes(run_dir / "episodes.csv")
    assert row["size_class"] == "small" and row["explored_pct"] < 95.0  # stuck by construction
    with (run_dir / "stuck.csv").open(newline="") as f:
        (stuck,) = list(csv.DictReader(f))
    assert tuple(stuck) == find_stuck.STUCK_FIELDS
    assert (stuck["method"], stuck["map"], stuck["robots"], stuck["episode"]) == ("greedy", SMALL_MAP, "2", "0")
    assert int(stuck["seed"]) == row["seed"] and stuck["reason"] == "explored"
    assert 0 <= int(stuck["stalled_from_step"]) <= int(stuck["last_step"]) <= 120
    assert stuck["replay_matches"] == "True"
    picture = run_dir / stuck["picture"]
    assert picture == run_dir / "stuck" / f"greedy-{SMALL_MAP}-r2-e0.png"
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = (run_dir / "stuck.md").read_text()
    assert f"](stuck/greedy-{SMALL_MAP}-r2-e0.png)" in md and md.rstrip().endswith("1 stuck of 1 episodes")
    assert not list(run_dir.glob(".*.tmp"))  # written atomically, nothing left behind

    # --from scans the same folder to the same report, and prints it
    capsys.readouterr()
    csv_before = (run_dir / "stuck.csv").read_text()
    assert find_stuck.main(["--from", str(run_dir)]) == 0
    assert (run_dir / "stuck.csv").read_text() == csv_before
    printed = capsys.readouterr().out
    assert printed == (run_dir / "stuck.md").read_text() and "1 stuck of 1 episodes" in printed

    # a lower threshold: not stuck any more, still exit status 0
    assert find_stuck.main(["--from", str(run_dir), "--min-explored", "1"]) == 0
    assert "0 stuck of 1 episodes" in capsys.readouterr().out
    with (run_dir / "stuck.csv").open(newline="") as f:
        assert list(csv.DictReader(f)) == []


@pytest.mark.slow
def test_the_replay_reaches_the_csv_row_and_the_recorded_curve(run_dir: Path) -> None:
    (row,) = read_episodes(run_dir / "episodes.csv")
    run = find_stuck.load_run(run_dir)
    rep = find_stuck.replay(row["map"], row["robots"], row["seed"], row["method"], run.max_steps, run.settings)
    metrics = find_stuck.replay_metrics(rep)
    assert metrics == {k: row[k] for k in metrics}  # same seed, same result, every metric of the row
    curve = run.curves[find_stuck._key(row)]
    steps, explored, covered = rep.curve
    assert steps == curve["steps"]
    assert [round(v, 4) for v in explored] == curve["explored_pct"]
    assert [round(v, 4) for v in covered] == curve["covered_pct"]
    # stopping at a decision's step leaves the env exactly there
    part = find_stuck.replay(row["map"], row["robots"], row["seed"], row["method"], run.max_steps, until=steps[1])
    assert part.curve == (steps[:2], explored[:2], covered[:2])


@pytest.mark.slow
def test_the_protocol_reaches_the_run_and_the_replay(tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert find_stuck.main(["--out", str(out), *RUN, "--workers", "1", "--protocol", "passby"]) == 0
    run = find_stuck.load_run(out)
    assert run.settings == {"world.protocol": "passby"}
    with (out / "stuck.csv").open(newline="") as f:
        (stuck,) = list(csv.DictReader(f))
    assert stuck["replay_matches"] == "True"
    (row,) = run.rows
    rep = find_stuck.replay(row["map"], row["robots"], row["seed"], row["method"], run.max_steps, run.settings)
    assert rep.env.config.world.protocol == "passby"
    metrics = find_stuck.replay_metrics(rep)
    assert metrics == {k: row[k] for k in metrics}


# ---------------------------------------------------------------------------------- bad input


def _error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    assert find_stuck.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("find_stuck: error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    return err


def test_a_from_folder_without_episodes_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert "episodes.csv" in _error(capsys, ["--from", str(tmp_path)])
    assert "no such folder" in _error(capsys, ["--from", str(tmp_path / "missing")])
    assert not list(tmp_path.iterdir())


def test_an_unknown_method_is_refused_before_anything_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    assert "nosuch" in _error(capsys, ["--out", str(out), "--methods", "greedy", "nosuch", "--maps", SMALL_MAP])
    assert not out.exists()


def test_bad_arguments_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _error(capsys, [])  # neither --out nor --from
    _error(capsys, ["--out", str(tmp_path / "a"), "--from", str(tmp_path)])
    _error(capsys, ["--out", str(tmp_path / "a"), "--robots", "three"])
    _error(capsys, ["--out", str(tmp_path / "a"), "--protocol", "sideways"])
    assert "--methods" in _error(capsys, ["--from", str(tmp_path), "--methods", "greedy"])
    assert "max-collisions" in _error(capsys, ["--from", str(tmp_path), "--max-collisions", "-1"])
    assert "robots" in _error(capsys, ["--out", str(tmp_path / "a"), "--robots", "99", "--maps", SMALL_MAP])
    assert not (tmp_path / "a").exists()


def test_a_map_that_is_not_bundled_needs_maps() -> None:
    with pytest.raises(find_stuck.InputError, match="--maps"):
        find_stuck.map_specs({"my_own_map"}, ["bundled"])
    assert find_stuck.map_specs({SMALL_MAP}, None) == {SMALL_MAP: SMALL_MAP}


@pytest.mark.slow
def test_the_command_line_reports_bad_input_without_a_traceback(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--from", str(tmp_path)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 2
    assert done.stderr.startswith("find_stuck: error: ") and done.stderr.count("\n") == 1
    assert done.stdout == ""
