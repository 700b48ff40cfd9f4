"""Kill and resume: ``areasearch eval`` killed with SIGKILL mid-run, then re-run with the same command,
ends with the files of an uninterrupted run: no corrupt file, no duplicated or missing episode, the
same numbers (``wall_s`` aside) in the same order. (``areasearch train`` has its own test.)"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from areasearch.harness.evaluate import CSV_FIELDS, EvalPlan, evaluate, read_curves, read_episodes

pytestmark = pytest.mark.slow  # every test here kills real processes

MAP = "bormann_lab_c_rooms1"
RUN = {"methods": ["greedy", "random"], "robots": [2], "maps": [MAP], "episodes": 4, "seed": 5, "max_steps": 160}


def _argv(out: Path, workers: int) -> list[str]:
    return [
        sys.executable, "-m", "areasearch.cli", "eval", "--methods", *RUN["methods"], "--robots", "2",
        "--maps", MAP, "--episodes", "4", "--seed", "5", "--max-steps", "160", "--out", str(out),
        "--workers", str(workers),
    ]  # fmt: skip


def _rows_on_disk(out: Path) -> int:
    path = out / "episodes.csv"
    return max(path.read_bytes().count(b"\n") - 1, 0) if path.exists() else 0


def _start(out: Path, workers: int) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        _argv(out, workers),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        start_new_session=True,  # its own process group: the kill takes its worker processes too
    )


def _kill_after(out: Path, workers: int, rows: int) -> None:
    """Start the command and SIGKILL it (and its workers) once ``rows`` episodes are on disk."""
    proc = _start(out, workers)
    deadline = time.monotonic() + 120
    try:
        while _rows_on_disk(out) < rows:
            assert proc.poll() is None, "the run ended before it could be killed"
            assert time.monotonic() < deadline, "no progress"
            time.sleep(0.005)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _without_wall(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if k != "wall_s"} for row in rows]


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("reference") / "run"
    evaluate(EvalPlan(**RUN, out=out), progress=None)  # type: ignore[arg-type]
    return out


@pytest.mark.parametrize("workers", [1, 2])
def test_eval_killed_twice_then_resumed_equals_an_uninterrupted_run(
    workers: int, reference: Path, tmp_path: Path
) -> None:
    out = tmp_path / "run"
    expected = _without_wall(read_episodes(reference / "episodes.csv"))
    for rows in (1, 4):
        _kill_after(out, workers, rows)
        # nothing corrupt: the files parse, and every finished row is the reference's row
        on_disk = _without_wall(read_episodes(out / "episodes.csv"))
        assert rows <= len(on_disk) <= len(expected)
        assert rows > 1 or len(on_disk) < len(expected)  # the first kill lands mid-run (two workers may finish
        # the last episodes together before the second one does)
        assert on_disk == expected[: len(on_disk)]
        assert json.loads((out / "config.json").read_text()) == json.loads((reference / "config.json").read_text())
        read_curves(out / "curves.jsonl")
    result = subprocess.run(_argv(out, workers), capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0, result.stderr
    lines = (out / "episodes.csv").read_text().splitlines()
    assert lines[0] == ",".join(CSV_FIELDS) and len(lines) == 1 + len(expected)
    assert _without_wall(read_episodes(out / "episodes.csv")) == expected
    assert (out / "curves.jsonl").read_bytes() == (reference / "curves.jsonl").read_bytes()
    for name in ("summary.json", "summary.md", "summary.tex"):
        assert (out / name).read_bytes() == (reference / name).read_bytes(), name
    assert not list(out.glob(".*.tmp"))


def test_a_curve_without_its_row_is_not_written_twice(reference: Path, tmp_path: Path) -> None:
    """A kill between an episode's curve and its row leaves the curve alone: the re-run drops it
    before playing the episode again."""
    out = tmp_path / "run"
    out.mkdir()
    for name in ("config.json", "curves.jsonl"):
        (out / name).write_bytes((reference / name).read_bytes())
    lines = (reference / "episodes.csv").read_text().splitlines(keepends=True)
    (out / "episodes.csv").write_text("".join(lines[:3]))  # rows of episodes 1-2, curves of all 6
    evaluate(EvalPlan(**RUN, out=out), progress=None)  # type: ignore[arg-type]
    assert (out / "curves.jsonl").read_bytes() == (reference / "curves.jsonl").read_bytes()
    assert _without_wall(read_episodes(out / "episodes.csv")) == _without_wall(
        read_episodes(reference / "episodes.csv")
    )
