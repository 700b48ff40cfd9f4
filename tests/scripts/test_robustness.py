"""scripts/robustness.py: one evaluation folder per condition, checked against its name, paired with the
perfect world; tables and the figure."""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

CliRunner = Callable[..., subprocess.CompletedProcess[str]]

EVAL = ("eval", "--methods", "greedy", "random", "--robots", "3", "--episodes", "2", "--max-steps", "120")


@pytest.mark.slow
def test_conditions_are_paired_with_the_perfect_world(
    tmp_path: Path, root: Path, run_cli: CliRunner, small_map: str
) -> None:
    study = tmp_path / "study"
    comm = ("--set", "world.comm.model=disc", "--set", "world.comm.range_m=0.5")
    for name, extra in (("none", ()), ("comm-0.5m", comm)):
        done = run_cli(*EVAL, "--maps", small_map, "--out", str(study / name), *extra)
        assert done.returncode == 0, done.stderr
    script = [sys.executable, str(root / "scripts" / "robustness.py"), str(study), "--robots", "3"]
    out = subprocess.run([*script, "--plot", str(tmp_path / "fig.png")], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "## 3 robots, by comm range" in out.stdout and "by preset" not in out.stdout
    rows = [line for line in out.stdout.splitlines() if line.startswith(("| greedy", "| random"))]
    assert len(rows) == 4
    paired = [line for line in rows if "| comm-0.5m |" in line]
    assert all(line.rstrip(" |").endswith("| 2") and "±" in line.split("|")[6] for line in paired)
    assert (tmp_path / "fig.png").read_bytes().startswith(b"\x89PNG")
    wide = subprocess.run([*script, "--wide", "--lead", "greedy"], capture_output=True, text=True)
    assert wide.returncode == 0, wide.stderr
    assert "| Method | none | comm-0.5m |" in wide.stdout and "| greedy minus | none | comm-0.5m |" in wide.stdout
    assert "| greedy (2) | " in wide.stdout and "| random | " in wide.stdout
    # the change of the lead is the lead under the condition minus the lead in the perfect world
    lead, change = (
        [float(c.split("±")[0].strip(" *")) for c in line.split("|")[2:-1]]
        for line in wide.stdout.splitlines()
        if line.startswith("| random | ")
    )
    assert len(lead) == 2 and len(change) == 1
    assert change[0] == pytest.approx(lead[1] - lead[0], abs=0.11)
    assert "| change of greedy's lead | comm-0.5m |" in wide.stdout
    cover = subprocess.run([*script, "--wide", "--lead", "greedy", "--metric", "cover"], capture_output=True, text=True)
    assert cover.returncode == 0, cover.stderr
    assert "Cover %, greedy minus each method" in cover.stdout and "Coverage AUC, greedy" not in cover.stdout

    shutil.copytree(study / "none", study / "comm-2m")  # a folder whose settings are not its name's
    wrong = subprocess.run(script, capture_output=True, text=True)
    assert wrong.returncode == 2 and wrong.stdout == ""
    assert wrong.stderr.strip().endswith("named comm-2m but its config.json records another communication")
    assert len(wrong.stderr.strip().splitlines()) == 1
