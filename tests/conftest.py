"""Fixtures shared by the test folders (which mirror the package's floors): where the repository, its
examples and the test data lie, the bundled map most tests run on, a tiny training config, a runner of
the ``areasearch`` command in a subprocess, the walled room the path-planning tests drive in, a user's
half-known map, an episode played to its end, and an ``areasearch serve`` process spoken to over HTTP
(:class:`Service`, started by the ``start_service`` fixture).

Test modules take these as fixtures and never import this file; a module that needs a value at import
time (a parametrize list) keeps its own constant."""

from __future__ import annotations

import http.client
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from areasearch.config import TargetConfig, WorldConfig, search_config
from areasearch.envs.goal import AreaSearchEnv
from areasearch.harness.evaluate import make_env, make_planner, planner_rng
from areasearch.planners import GoalPlanner
from areasearch.service.assign import OccupancyMap, occupancy_from_array
from areasearch.sim.scene import scene_from_grid
from areasearch.sim.world import World

TESTS = Path(__file__).resolve().parent
START_S = 600.0
"""Longest start-up of a service (a first run compiles numba's kernels; a warm cache takes a few seconds)."""

CliRunner = Callable[..., "subprocess.CompletedProcess[str]"]
RoomWorld = Callable[..., World]


@pytest.fixture(scope="session")
def root() -> Path:
    """The repository's root folder."""
    return TESTS.parent


@pytest.fixture(scope="session")
def examples(root: Path) -> Path:
    """The ``examples/`` folder: a partial map, robots and targets files."""
    return root / "examples"


@pytest.fixture(scope="session")
def bad_inputs() -> Path:
    """The bad-input corpus, ``tests/bad_inputs/`` (its good files included)."""
    return TESTS / "bad_inputs"


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """``tests/data/``: saved policies and episodes the tests compare against."""
    return TESTS / "data"


@pytest.fixture(scope="session")
def tiny_training(bad_inputs: Path) -> Path:
    """A training config small enough to run in seconds (the corpus's good ``train`` file)."""
    return bad_inputs / "train" / "good.toml"


@pytest.fixture(scope="session")
def small_map() -> str:
    """The bundled small map most environment and planner tests run on."""
    return "bormann_lab_c_rooms1"


@pytest.fixture(scope="session")
def run_cli() -> CliRunner:
    """A function that runs ``python -m areasearch.cli ARGS`` and returns the finished process (text
    output captured, never raising on a non-zero exit). Options: ``cwd``, ``env`` (added to this
    process's environment), ``timeout`` (seconds, 120 unless given), ``input`` (text on its standard input)."""

    def run(
        *args: str,
        cwd: Path | None = None,
        env: Mapping[str, str] | None = None,
        timeout: float = 120,
        input: str | None = None,
    ) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "areasearch.cli", *args],
            input=input,
            capture_output=True,
            text=True,
            cwd=cwd,
            env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
            timeout=timeout,
            check=False,
        )

    return run


@pytest.fixture
def room_world() -> RoomWorld:
    """A function that makes a 5.2 x 3.2 m room (0.05 m cells) with an inner wall whose way round is
    at the north end, reset with seed 0: ``room_world(num_robots=1, known=False)``; ``known`` marks
    the whole room explored and its obstacles occupied, as if already mapped."""

    def make(num_robots: int = 1, known: bool = False) -> World:
        free = np.zeros((64, 104), dtype=bool)
        free[2:62, 2:102] = True
        free[2:50, 50:53] = False  # an inner wall; the way round is at the north end
        world = World(WorldConfig(num_robots=num_robots, targets=TargetConfig(count=5)))
        world.reset(scene_from_grid("room", free, 0.05), np.random.default_rng(0))
        if known:
            world.mapper.explored[:] = True
            world.mapper.occupied[:] = ~world.scene.free
        return world

    return make


@pytest.fixture
def sarmis_played() -> tuple[AreaSearchEnv, dict[str, Any]]:
    """``robotathome_sarmis`` with 3 robots (seed 4) after 3 greedy decisions, and its last observation:
    a team's own partial map and history, to compare with what a user's map gives."""
    env = AreaSearchEnv(map="robotathome_sarmis", num_robots=3, seed=4)
    obs, _ = env.reset(seed=4)
    planner = make_planner("greedy")
    planner.reset(planner_rng(4))
    for _ in range(3):
        obs, *_ = env.step(planner.assign(obs))
    return env, obs


@pytest.fixture(scope="session")
def half_known() -> Callable[..., OccupancyMap]:
    """A function that makes a user's map: a 6 x 3 m room (0.1 m cells) walled all round; its western
    half (ix 1-29) known free, the eastern half unknown (-1): one straight frontier at ix = 29,
    x = 2.95 m from the origin. ``half_known(origin=(0.0, 0.0))``."""

    def make(origin: tuple[float, float] = (0.0, 0.0)) -> OccupancyMap:
        data = np.full((30, 60), -1, dtype=np.int8)
        data[:, :30] = 0
        data[[0, -1], :] = 100
        data[:, [0, -1]] = 100
        return occupancy_from_array(data, 0.1, origin)

    return make


@pytest.fixture(scope="session")
def play_passby() -> Callable[..., tuple[dict[str, Any], Any]]:
    """A function that plays one whole episode (3600 steps at most) under the ``passby`` protocol, the
    rule the replayed failures were found under: ``play_passby(map_id, method, robots, seed)``, the
    method a name or a planner; returns the last ``info`` and the environment."""

    def play(map_id: str, method: str | GoalPlanner, robots: int, seed: int) -> tuple[dict[str, Any], Any]:
        env = make_env(map_id, robots, seed, 3600, search_config({"world.protocol": "passby"}))
        planner = make_planner(method) if isinstance(method, str) else method
        obs, info = env.reset(seed=seed)
        planner.reset(planner_rng(seed))
        done = False
        while not done:
            obs, _, terminated, truncated, info = env.step(planner.assign(obs))
            done = terminated or truncated
        return info, env

    return play


@dataclass
class Service:
    """A running ``areasearch serve`` process, its URL and its log."""

    proc: subprocess.Popen[bytes]
    host: str
    port: int
    log_path: Path
    token: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def request(
        self,
        method: str,
        path: str,
        body: Any = None,
        *,
        raw: bytes | None = None,
        token: str | bool | None = True,
        headers: dict[str, str] | None = None,
        timeout: float = 120.0,
    ) -> tuple[int, Any]:
        """(status, the parsed JSON or the text) of one request; ``token=True``: the service's token; a
        header given as "" is left out (``Content-Type`` is application/json with a body, else)."""
        conn = http.client.HTTPConnection(self.host, self.port, timeout=timeout)
        sent = dict(headers or {})
        bearer = self.token if token is True else token
        if bearer:
            sent["Authorization"] = f"Bearer {bearer}"
        data = raw if raw is not None else (None if body is None else json.dumps(body).encode())
        if data is not None:
            sent.setdefault("Content-Type", "application/json")
        sent = {k: v for k, v in sent.items() if v}
        try:
            conn.request(method, path, body=data, headers=sent)
            response = conn.getresponse()
            text = response.read().decode()
        finally:
            conn.close()
        try:
            return response.status, json.loads(text)
        except json.JSONDecodeError:
            return response.status, text

    def text(self, body: dict[str, Any]) -> str:
        """The body of a successful ``POST /assign``, as text."""
        conn = http.client.HTTPConnection(self.host, self.port, timeout=120)
        try:
            conn.request(
                "POST",
                "/assign",
                body=json.dumps(body).encode(),
                headers={"Content-Type": "application/json", **self._auth()},
            )
            response = conn.getresponse()
            text = response.read().decode()
        finally:
            conn.close()
        assert response.status == 200, text
        return text

    def _auth(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.token}"} if self.token else {}

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def worker_pids(self) -> set[int]:
        """Pids of the service's child processes (its workers), from /proc."""
        pids = set()
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == self.proc.pid:
                pids.add(int(stat.parent.name))
        return pids

    def wait_idle(self, workers: int, timeout: float = START_S) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            status, doc = self.request("GET", "/health", token=None)
            if status == 200 and doc["idle_workers"] >= workers:
                return
            time.sleep(0.2)
        raise AssertionError(f"no {workers} idle workers within {timeout} s:\n{self.log()[-3000:]}")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def _start(
    tmp: Path, *args: str, token: str | None = None, wait: bool = True, env: Mapping[str, str] | None = None
) -> Service:
    """``areasearch serve --port 0 ARGS`` in a subprocess; its port read from its first line; ``env``
    added to this process's environment, less any ``AREASEARCH_SERVE_TOKEN`` unless ``token``."""
    log_path = tmp / "serve.log"
    environment = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
    environment.pop("AREASEARCH_SERVE_TOKEN", None)
    if token:
        environment["AREASEARCH_SERVE_TOKEN"] = token
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "areasearch.cli", "serve", "--port", "0", *args],
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env=environment,
        )
    end = time.monotonic() + START_S
    while True:
        found = re.search(r"listening on http://([0-9.]+):(\d+)", log_path.read_text(errors="replace"))
        if found:
            break
        if proc.poll() is not None or time.monotonic() > end:
            proc.kill()
            raise AssertionError(f"the service did not start:\n{log_path.read_text()}")
        time.sleep(0.05)
    service = Service(proc, found.group(1), int(found.group(2)), log_path, token)
    if wait:
        end = time.monotonic() + START_S
        while service.request("GET", "/health", token=None)[0] != 200:
            if proc.poll() is not None or time.monotonic() > end:
                service.stop()
                raise AssertionError(f"the service did not get ready:\n{service.log()}")
            time.sleep(0.1)
    return service


@pytest.fixture(scope="session")
def start_service() -> Callable[..., Service]:
    """A function that starts ``areasearch serve --port 0 ARGS`` in a subprocess and returns it
    ready (``wait``) to be spoken to over HTTP: ``start_service(folder, *args, token=None,
    wait=True, env=None)``, its log in ``folder/serve.log``; the caller stops it."""
    return _start
