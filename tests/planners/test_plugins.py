"""Plug-in planners: a planner of another installed distribution, found through the entry-point group
``areasearch.planners``, works wherever a planner name does (``make_planner``, ``assign_goals``,
``run``, ``render``, ``eval`` with worker processes, ``assign``, ``serve``) and is listed by
``areasearch methods`` with its distribution; a broken plug-in is one clear error naming it when it is
asked for, and hides nothing: ``greedy`` still works and is still listed.

The distribution is real: a package and its ``*.dist-info`` folder (``METADATA``, ``entry_points.txt``)
written into a temporary folder that is put on the path (``sys.path`` here, ``PYTHONPATH`` for the
subprocesses), which is all an installed distribution is to :mod:`importlib.metadata`.
"""

from __future__ import annotations

import functools
import json
import os
import re
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from textwrap import dedent
from typing import Any

import pytest

from areasearch.errors import ConfigError
from areasearch.planners import PLANNERS, GoalPlanner, GreedyPlanner, choose_planner, describe_planners, make_planner
from areasearch.service.assign import OccupancyMap, assign_goals

HalfKnown = Callable[..., OccupancyMap]

CliRunner = Callable[..., subprocess.CompletedProcess[str]]

MAP = "wrs2020_arena"

PLANNER_MODULE = '''
"""A plug-in planner for the tests: each robot's farthest allowed candidate."""

import os

import numpy as np


class Farthest:
    """Each robot takes its farthest allowed candidate."""

    def __init__(self, name="farthest", weights=None):
        self.name = name
        self.weights = weights

    def reset(self, rng):
        self.rng = rng

    def assign(self, obs):
        mark = os.environ.get("PLUGIN_MARKS")
        if mark:  # proof that this process planned with the plug-in
            with open(os.path.join(mark, str(os.getpid())), "a") as f:
                f.write("x")
        allowed = np.asarray(obs["action_mask"]).astype(bool)
        dist = np.where(allowed, np.nan_to_num(np.asarray(obs["distances"], float), posinf=1e9), -np.inf)
        return np.where(allowed.any(axis=1), np.argmax(dist, axis=1), 0).astype(np.int64)


def make_planner():
    """Each robot's farthest allowed candidate (a test plug-in)."""
    return Farthest()


def make_weighted(weights=None):
    return Farthest("weighted", weights)


def make_raising():
    raise RuntimeError("the plug-in's own failure")


def make_nothing():
    return 42


NOT_CALLABLE = "a string"
'''

DISTRIBUTIONS = {
    "farplug": (
        "0.1",
        {"farplug/__init__.py": PLANNER_MODULE},
        """
        [areasearch.planners]
        farthest = farplug:make_planner
        weighted = farplug:make_weighted
        greedy = farplug:make_planner
        raises = farplug:make_raising
        not-a-planner = farplug:make_nothing
        not-callable = farplug:NOT_CALLABLE
        """,
    ),
    "brokenplug": (
        "1.0",
        {"brokenplug/__init__.py": "import a_module_that_is_not_installed\n"},
        """
        [areasearch.planners]
        broken = brokenplug:make_planner
        """,
    ),
}


def install(site: Path) -> Path:
    """The distributions of :data:`DISTRIBUTIONS` as installed in the folder ``site``."""
    for dist, (version, files, entry_points) in DISTRIBUTIONS.items():
        for name, text in files.items():
            (site / name).parent.mkdir(parents=True, exist_ok=True)
            (site / name).write_text(text)
        info = site / f"{dist}-{version}.dist-info"
        info.mkdir()
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n")
        (info / "entry_points.txt").write_text(dedent(entry_points).lstrip())
    return site


@pytest.fixture
def site(tmp_path: Path) -> Iterator[Path]:
    """The distributions installed on this process's path, the registry re-read; undone afterwards."""
    folder = install(tmp_path / "site")
    sys.path.insert(0, str(folder))
    PLANNERS.rediscover()
    try:
        yield folder
    finally:
        sys.path.remove(str(folder))
        for module in ("farplug", "brokenplug"):
            sys.modules.pop(module, None)
        PLANNERS.rediscover()


# ---------------------------------------------------------------------------------- in this process


def test_a_plug_in_is_a_planner_like_the_built_in_ones(site: Path, half_known: HalfKnown) -> None:
    assert "farthest" in PLANNERS and "farthest" in list(PLANNERS)
    planner = make_planner("farthest")
    assert isinstance(planner, GoalPlanner) and type(planner).__module__ == "farplug"
    poses = [(1.05, 1.55, 0.0), (0.55, 0.55, 0.5)]
    far = assign_goals(half_known(), poses, "farthest", targets=[(2.0, 0.6)])
    near = assign_goals(half_known(), poses, "greedy", targets=[(2.0, 0.6)])
    assert far != near and all(a.goal_xy is not None for a in far)
    assert choose_planner("farthest").method == "farthest"
    # a plug-in that takes weights gets them; one that does not is refused like a classical planner
    assert make_planner("weighted", weights="some/prefix").weights == "some/prefix"  # type: ignore[attr-defined]
    with pytest.raises(ConfigError, match="planner 'farthest' takes no weights"):
        make_planner("farthest", weights="some/prefix")
    with pytest.raises(ConfigError, match="planner 'farthest': got an unexpected keyword argument 'speed'"):
        make_planner("farthest", speed=2)


def test_a_built_in_name_wins_and_the_plug_in_is_reported(site: Path) -> None:
    assert isinstance(make_planner("greedy"), GreedyPlanner)
    rows = [r for r in describe_planners() if r["name"] == "greedy"]
    assert [r["origin"] for r in rows] == ["built-in classical", "plug-in farplug 0.1"]
    assert rows[1]["status"] == "ignored" and "'greedy' is a built-in planner" in rows[1]["error"]


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("broken", "plug-in planner 'broken' (brokenplug 1.0, brokenplug:make_planner): cannot be imported: "
                   "ModuleNotFoundError: No module named 'a_module_that_is_not_installed'"),
        ("raises", "plug-in planner 'raises' (farplug 0.1, farplug:make_raising): its factory raised "
                   "RuntimeError: the plug-in's own failure"),
        ("not-a-planner", "plug-in planner 'not-a-planner' (farplug 0.1, farplug:make_nothing): its factory "
                          "returned 42, not a GoalPlanner"),
        ("not-callable", "plug-in planner 'not-callable' (farplug 0.1, farplug:NOT_CALLABLE): is not callable (a str)"),
    ],
)  # fmt: skip
def test_a_broken_plug_in_is_one_error_when_asked_for_and_hides_nothing(
    site: Path, name: str, message: str, half_known: HalfKnown
) -> None:
    assert name in PLANNERS  # listed, so that asking for it gets its own error rather than "unknown"
    with pytest.raises(ConfigError) as err:
        make_planner(name)
    assert str(err.value).startswith(message) and "\n" not in str(err.value)
    with pytest.raises(ConfigError, match=re.escape(message)):
        assign_goals(half_known(), [(1.05, 1.55, 0.0)], name)
    (row,) = [r for r in describe_planners() if r["name"] == name]
    assert row["status"] == "broken" and row["error"].startswith(message)
    assert isinstance(make_planner("greedy"), GreedyPlanner)  # the built-ins are untouched
    assert {r["name"] for r in describe_planners() if r["status"] == "ok"} >= {"greedy", "farthest", "dahgnn-untrained"}


def test_plug_ins_are_read_on_first_use_not_at_import() -> None:
    code = (
        "import sys, areasearch, areasearch.planners as p, areasearch.cli; "
        "assert p.PLANNERS._discovery is None; "
        "areasearch.cli.build_parser(); assert p.PLANNERS._discovery is None; "
        "p.make_planner('greedy'); assert p.PLANNERS._discovery is None; "
        "p.make_planner('dahgnn-untrained'); assert p.PLANNERS._discovery is None; "
        "'farthest' in p.PLANNERS; assert p.PLANNERS._discovery is not None"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


# ---------------------------------------------------------------------------------- the commands


@pytest.fixture
def plugin_cli(installed: tuple[Path, Path], run_cli: CliRunner) -> CliRunner:
    """``run_cli`` for a process with the distributions of :func:`installed` on its path."""
    site, marks = installed
    env = {"PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")]), "PLUGIN_MARKS": str(marks)}
    return functools.partial(run_cli, env=env, timeout=600)


@pytest.fixture
def installed(tmp_path: Path) -> tuple[Path, Path]:
    """The distributions installed in a folder for subprocesses (on their PYTHONPATH), and a folder
    where the plug-in marks each process that planned with it."""
    (tmp_path / "marks").mkdir()
    return install(tmp_path / "site2"), tmp_path / "marks"


@pytest.mark.slow  # subprocesses
def test_areasearch_methods_lists_every_planner_with_its_origin(plugin_cli: CliRunner) -> None:
    result = plugin_cli("methods", "--json")
    assert result.returncode == 0, result.stderr
    rows = {(r["name"], r["origin"]): r for r in json.loads(result.stdout)}
    assert rows["greedy", "built-in classical"]["status"] == "ok"
    assert rows["dahgnn-untrained", "untrained network"]["status"] == "ok"
    shipped = rows["dahgnn", "shipped learned policy"]
    assert re.fullmatch(r"[0-9a-f]{64}", shipped["weights_sha256"])
    farthest = rows["farthest", "plug-in farplug 0.1"]
    assert farthest["status"] == "ok" and farthest["entry_point"] == "farplug:make_planner"
    assert farthest["description"] == "Each robot's farthest allowed candidate (a test plug-in)."
    assert rows["broken", "plug-in brokenplug 1.0"]["status"] == "broken"
    assert rows["greedy", "plug-in farplug 0.1"]["status"] == "ignored"
    text = plugin_cli("methods")
    assert text.returncode == 0, text.stderr
    lines = text.stdout.splitlines()
    assert any(re.match(r"farthest +plug-in farplug 0\.1 +Each robot's farthest", line) for line in lines)
    assert any(re.match(r"broken +plug-in brokenplug 1\.0 \(broken\)", line) for line in lines)
    assert any("No module named 'a_module_that_is_not_installed'" in line for line in lines)
    assert any(re.match(r"greedy +built-in classical", line) for line in lines)


@pytest.mark.slow  # subprocesses playing episodes
def test_run_render_eval_and_assign_use_a_plug_in(
    installed: tuple[Path, Path], tmp_path: Path, plugin_cli: CliRunner, examples: Path
) -> None:
    marks = installed[1]
    episode = ["--map", MAP, "--robots", "2", "--max-steps", "40"]
    result = plugin_cli("run", "--method", "farthest", *episode, "--out", str(tmp_path / "a.png"))
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["method"] == "farthest"
    result = plugin_cli("render", "--method", "farthest", *episode, "--out", str(tmp_path / "a.gif"))
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["method"] == "farthest" and (tmp_path / "a.gif").is_file()
    planned_here = set(os.listdir(marks))
    # eval: the worker processes find the plug-in by its name
    out = tmp_path / "results"
    result = plugin_cli("eval", "--methods", "farthest", "greedy", "--maps", MAP, "--robots", "2",
                  "--episodes", "2", "--max-steps", "40", "--workers", "2", "--out", str(out))  # fmt: skip
    assert result.returncode == 0, result.stderr
    rows = (out / "episodes.csv").read_text().splitlines()
    assert sum(line.startswith("farthest,") for line in rows) == 2
    assert "farthest" in (out / "summary.md").read_text()
    assert set(os.listdir(marks)) - planned_here  # planned in other processes: the workers
    args = ["assign", "--map", str(examples / "partial_map.yaml"), "--robots", str(examples / "robots.json")]
    result = plugin_cli(*args, "--method", "farthest")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["method"] == "farthest"


@pytest.mark.slow  # subprocesses
def test_a_broken_plug_in_is_one_error_in_every_command_and_greedy_still_works(
    tmp_path: Path, plugin_cli: CliRunner, examples: Path
) -> None:
    expect = "areasearch: error: plug-in planner 'broken' (brokenplug 1.0, brokenplug:make_planner): cannot be imported"
    episode = ["--map", MAP, "--robots", "2", "--max-steps", "40"]
    assign = ["assign", "--map", str(examples / "partial_map.yaml"), "--robots", str(examples / "robots.json")]
    for args in (
        ["run", *episode, "--out", str(tmp_path / "a.png")],
        ["render", *episode, "--out", str(tmp_path / "a.gif")],
        ["eval", "--maps", MAP, "--robots", "2", "--episodes", "1", "--max-steps", "40", "--out", str(tmp_path / "r")],
        assign,
    ):
        method = ["--methods", "greedy", "broken"] if args[0] == "eval" else ["--method", "broken"]
        result = plugin_cli(*args, *method)
        assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
        (line,) = result.stderr.strip().splitlines()
        assert line.startswith(expect), line
        assert not any(tmp_path.glob("a.*")) and not (tmp_path / "r").exists()
    result = plugin_cli("run", *episode, "--method", "greedy", "--out", str(tmp_path / "a.png"))
    assert result.returncode == 0 and json.loads(result.stdout)["method"] == "greedy", result.stderr


@pytest.mark.slow  # a service with a worker process
def test_the_service_plans_with_a_plug_in_and_refuses_a_broken_one(
    installed: tuple[Path, Path], examples: Path, start_service: Callable[..., Any]
) -> None:
    site, marks = installed
    env = {"PYTHONPATH": str(site), "PLUGIN_MARKS": str(marks)}
    service = start_service(marks.parent, "--method", "farthest", env=env)
    try:
        from areasearch.service.assign import load_occupancy
        from areasearch.service.occupancy_msg import grid_message

        body = {
            "map": grid_message(load_occupancy(examples / "partial_map.yaml")),
            "robots": json.loads((examples / "robots.json").read_text())["robots"],
        }
        status, doc = service.request("POST", "/assign", body)
        assert status == 200 and doc["method"] == "farthest", doc
        status, doc = service.request("POST", "/assign", {**body, "method": "broken"})
        assert status == 422 and "plug-in planner 'broken' (brokenplug 1.0" in str(doc["detail"]), doc
        status, doc = service.request("POST", "/assign", {**body, "method": "greedy"})
        assert status == 200 and doc["method"] == "greedy", doc
        status, doc = service.request("GET", "/methods")
        rows = {m["name"]: m for m in doc["methods"]}
        assert rows["farthest"]["origin"] == "plug-in farplug 0.1" and rows["farthest"]["status"] == "ok"
        assert rows["broken"]["status"] == "broken" and rows["greedy"]["kind"] == "classical"
    finally:
        service.stop()
