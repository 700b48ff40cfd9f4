"""``areasearch serve`` (:mod:`areasearch.service.serve`): the service is started in a subprocess on a free
port and spoken to with a real HTTP client (``http.client``), as a robot stack would.

Two services: ``service`` (2 workers, a token, short connection deadlines, a 10 s time limit) and
``tight`` (1 worker, no token, small limits: body, cells, time, connections). What is checked: an
answer equals ``assign_goals`` and, byte for byte, ``areasearch assign``; the OccupancyGrid's row 0
lies at the origin; maps stored by ``PUT /maps`` are used by name; 4 concurrent clients get the
serial answers; the bad-request table (:data:`CASES`, in the style of ``tests/test_bad_inputs.py``)
and the CLI corpus's robots and targets files (the same messages as ``areasearch assign``); the
token, and without one the ``Host`` and ``Content-Type`` rules (:data:`OPEN_CASES`); 413 for large
bodies and maps; on real sockets, idle, slow-head and slow-body connections closed on time and the
bound on open connections; a request over the time limit and one whose client hangs up stop their
worker process; a worker killed while idle is replaced, its request served; and a property test
(hypothesis): a good request with random JSON in its fields gets 200 or one 4xx line, never a 500.
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from areasearch.errors import MapError
from areasearch.service.assign import (
    OccupancyMap,
    assign_goals,
    assignments_json,
    dumps,
    load_occupancy,
    occupancy_from_array,
    robots_from_json,
    targets_from_json,
)
from areasearch.service.occupancy_msg import OccupancyGrid, grid_cells, grid_message

CliRunner = Callable[..., subprocess.CompletedProcess[str]]

TESTS = Path(__file__).resolve().parents[1]
EXAMPLES = TESTS.parent / "examples"
CORPUS = TESTS / "bad_inputs"  # read at import time, for CLI_ROWS
TOKEN = "s3cret-token"
TIGHT_CONNECTIONS = 8
"""``--max-connections`` of the ``tight`` service."""
Service = Any
"""A running ``areasearch serve`` process, the ``start_service`` fixture's (``tests/conftest.py``)."""
StartService = Callable[..., Service]


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory, start_service: StartService) -> Iterator[Service]:
    s = start_service(
        tmp_path_factory.mktemp("service"), "--workers", "2", "--time-limit-s", "10", "--idle-timeout-s", "2",
        "--header-timeout-s", "1", token=TOKEN,
    )  # fmt: skip
    yield s
    s.stop()


@pytest.fixture(scope="module")
def tight(tmp_path_factory: pytest.TempPathFactory, start_service: StartService) -> Iterator[Service]:
    s = start_service(
        tmp_path_factory.mktemp("tight"),
        "--workers", "1", "--time-limit-s", "0.5", "--max-body-bytes", "16000000", "--max-map-cells", "4500000",
        "--idle-timeout-s", "2", "--header-timeout-s", "1", "--max-connections", str(TIGHT_CONNECTIONS),
    )  # fmt: skip
    yield s
    s.stop()


# ---------------------------------------------------------------------------------- inputs


def _examples() -> tuple[OccupancyMap, list[dict[str, Any]], list[dict[str, Any]]]:
    grid = load_occupancy(EXAMPLES / "partial_map.yaml")
    robots = json.loads((EXAMPLES / "robots.json").read_text())["robots"]
    targets = json.loads((EXAMPLES / "targets.json").read_text())["targets"]
    return grid, robots, targets


def _library_text(grid: OccupancyMap, body: dict[str, Any], method: str = "greedy", config: Any = None) -> str:
    """What ``areasearch assign`` prints for ``body``'s robots and targets on ``grid`` (``config``: its
    ``--set`` settings as a SearchConfig)."""
    robots = robots_from_json(body["robots"], "request")
    target_ids, targets = targets_from_json(body.get("targets", []), "request")
    assignments = assign_goals(
        grid,
        robots.poses,
        method,
        targets if target_ids else None,
        robots.past_positions,
        robots.past_goals,
        config=config,
        seed=body.get("seed", 0),
        robot_names=robots.ids,
    )
    return dumps(assignments_json(assignments, robots.ids, target_ids, method))


def _corpus_map() -> dict[str, Any]:
    """``tests/bad_inputs/ros/good.yaml`` (the CLI corpus's good map) as an OccupancyGrid message."""
    return grid_message(load_occupancy(CORPUS / "ros" / "good.yaml"))


def _room(height: int = 30, width: int = 60) -> dict[str, Any]:
    """A walled room of 0.1 m cells, its western half known free, the rest unknown."""
    data = np.full((height, width), -1, dtype=np.int8)
    data[:, : width // 2] = 0
    data[[0, -1], :] = 100
    data[:, [0, -1]] = 100
    return grid_message(occupancy_from_array(data, 0.1))


def _big(n: int = 2000) -> dict[str, Any]:
    """An n x n map of 5 cm cells, three quarters known with walls: a few hundred ms per request."""
    data = np.full((n, n), -1, dtype=np.int8)
    data[: n * 3 // 4, : n * 3 // 4] = 0
    data[0, :] = 100
    data[:, 0] = 100
    for k in range(50, n * 3 // 4, 100):
        data[k, 10 : n * 3 // 4 - 40] = 100
    return grid_message(occupancy_from_array(data, 0.05))


EIGHT = [{"id": f"r{i}", "x": 1.0 + 0.6 * i, "y": 1.3, "yaw": 0.0} for i in range(8)]
"""Eight robots in the south-west of :func:`_big`."""


# ---------------------------------------------------------------------------------- answers


def test_health_methods_schema_and_docs(service: Service) -> None:
    status, doc = service.request("GET", "/health", token=None)
    assert status == 200 and doc["status"] == "ready" and doc["workers"] == 2
    status, doc = service.request("GET", "/methods")
    assert status == 200 and doc["default"] == "greedy"
    kinds = {m["name"]: m["kind"] for m in doc["methods"]}
    assert kinds["greedy"] == "classical" and kinds["voronoi"] == "classical"
    assert kinds["dahgnn-untrained"] == "learned" and kinds["ncm-untrained"] == "learned"
    assert all(m["description"] and "\n" not in m["description"] for m in doc["methods"])
    status, schema = service.request("GET", "/openapi.json")
    assert status == 200
    assert {"/assign", "/maps/{name}", "/maps", "/health", "/methods"} <= set(schema["paths"])
    components = schema["components"]["schemas"]
    assert {"AssignRequest", "OccupancyGrid", "MapMetaData"} <= set(components)
    body = schema["paths"]["/assign"]["post"]["requestBody"]["content"]["application/json"]["schema"]
    assert body == {"$ref": "#/components/schemas/AssignRequest"}
    refs = re.findall(r'"\$ref": "#/components/schemas/(\w+)"', json.dumps(schema))
    assert set(refs) <= set(components)  # every reference resolves
    status, page = service.request("GET", "/docs")
    assert status == 200 and "swagger" in page.lower()


def test_the_token_is_wanted_everywhere_but_health(service: Service) -> None:
    for method, path in (("GET", "/methods"), ("GET", "/maps"), ("GET", "/openapi.json"), ("GET", "/docs"),
                         ("POST", "/assign"), ("PUT", "/maps/x"), ("DELETE", "/maps/x")):  # fmt: skip
        for token in (None, "wrong", TOKEN + "x"):
            status, doc = service.request(method, path, {"map": "x"}, token=token)
            assert status == 401, (method, path, token, doc)
            assert "Authorization: Bearer" in doc["detail"]
    status, _ = service.request("GET", "/maps", headers={"Authorization": f"Basic {TOKEN}"}, token=None)
    assert status == 401
    assert service.request("GET", "/health", token=None)[0] == 200
    assert service.request("GET", "/maps")[0] == 200


def test_an_answer_is_the_library_call_and_the_cli_output(service: Service, capsys: pytest.CaptureFixture[str]) -> None:
    from areasearch.cli import main

    grid, robots, targets = _examples()
    message = grid_message(grid)
    for method, seed in (("greedy", 0), ("voronoi", 3), ("random", 7), ("dahgnn-untrained", 0)):
        body = {"map": message, "robots": robots, "targets": targets, "method": method, "seed": seed}
        text = service.text(body)
        assert text == _library_text(grid, body, method), method
        args = ["assign", "--map", str(EXAMPLES / "partial_map.yaml"), "--robots", str(EXAMPLES / "robots.json")]
        args += ["--targets", str(EXAMPLES / "targets.json"), "--method", method, "--seed", str(seed)]
        assert main(args) == 0
        assert capsys.readouterr().out == text, method  # byte for byte what `areasearch assign` prints
    doc = json.loads(text)
    assert doc["method"] == "dahgnn-untrained" and [r["id"] for r in doc["robots"]] == [r["id"] for r in robots]
    # no method: the service's default; no targets: no dropped_targets, as the CLI
    plain = json.loads(service.text({"map": message, "robots": robots}))
    assert plain["method"] == "greedy" and "dropped_targets" not in plain


def test_the_settings_of_serve_set_apply_to_every_request(tmp_path: Path, start_service: StartService) -> None:
    from areasearch.config import search_config

    tight = start_service(tmp_path, "--workers", "1", "--set", "candidates.distance_cell_m=0.1")
    status, doc = tight.request("GET", "/health", token=None)
    assert status == 200 and doc["settings"] == {"candidates.distance_cell_m": 0.1}
    grid, robots, targets = _examples()
    body = {"map": grid_message(grid), "robots": robots, "targets": targets, "method": "greedy", "seed": 0}
    coarse = search_config({"candidates.distance_cell_m": 0.1})
    try:
        assert tight.text(body) == _library_text(grid, body, "greedy", coarse)
    finally:
        tight.stop()


def test_row_0_of_the_grid_lies_at_the_origin(service: Service) -> None:
    """An asymmetric map: the southern rows free, the northern ones wall; a robot there is in a wall."""
    data = np.full((20, 30), 100, dtype=np.int8)
    data[1:8, 1:29] = 0  # free: y from 0.1 to 0.8 above the origin (rows 1-7, row 0 at the origin)
    data[4, 20:] = -1  # unknown: a frontier in the east of the southern strip
    message = grid_message(occupancy_from_array(data, 0.1, (-2.0, 5.0)))
    message["data"] = data.reshape(-1).tolist()  # row-major, row 0 first: as a ROS node sends it
    cells = grid_cells(OccupancyGrid.model_validate(message)).cells
    assert (cells == data).all()
    status, doc = service.request("POST", "/assign", {"map": message, "robots": [{"x": -1.5, "y": 5.45}]})
    assert status == 200, doc
    (robot,) = doc["robots"]
    assert robot["type"] == "frontier" and 5.1 < robot["goal"][1] < 5.8 and robot["goal"][0] > -0.05
    status, doc = service.request("POST", "/assign", {"map": message, "robots": [{"x": -1.5, "y": 6.5}]})
    assert status == 422 and "stands on an occupied cell" in doc["detail"]


def test_stored_maps_are_used_by_name(service: Service) -> None:
    grid, robots, targets = _examples()
    message = grid_message(grid)
    status, doc = service.request("PUT", "/maps/flat-1", message)
    assert status == 201 and doc["name"] == "flat-1" and (doc["width"], doc["height"]) == grid.shape[::-1]
    assert service.request("PUT", "/maps/flat-1", message)[0] == 200  # an update
    assert [m["name"] for m in service.request("GET", "/maps")[1]["maps"]] == ["flat-1"]
    inline = service.text({"map": message, "robots": robots, "targets": targets, "method": "utility", "seed": 2})
    for _ in range(2):
        named = service.text({"map": "flat-1", "robots": robots, "targets": targets, "method": "utility", "seed": 2})
        assert named == inline
    status, doc = service.request("PUT", "/maps/..%2Fetc", message)
    assert status in (404, 422)
    status, doc = service.request("PUT", "/maps/no%20free", {**message, "data": [100] * len(message["data"])})
    assert status == 422 and "is not a map name" in doc["detail"]
    status, doc = service.request("PUT", "/maps/walls", {**message, "data": [100] * len(message["data"])})
    assert status == 422 and doc["detail"] == "maps/walls: the map has no free cell"
    assert service.request("DELETE", "/maps/flat-1")[0] == 204
    status, doc = service.request("POST", "/assign", {"map": "flat-1", "robots": robots})
    assert status == 422 and "no stored map named 'flat-1'" in doc["detail"]
    assert service.request("DELETE", "/maps/flat-1")[0] == 404


def test_concurrent_clients_get_the_serial_answers(service: Service) -> None:
    """Same request and seed, same answer: first or twentieth, alone or with 3 other clients."""
    grid, robots, targets = _examples()
    assert service.request("PUT", "/maps/flat-2", grid_message(grid))[0] == 201
    bodies = [
        {"map": "flat-2", "robots": robots[: 1 + k % 3], "targets": targets, "method": method, "seed": k}
        for k, method in enumerate(["random", "greedy", "utility", "voronoi", "coscan", "hungarian", "random",
                                    "ncm-untrained"])
    ]  # fmt: skip
    serial = [service.text(b) for b in bodies]
    assert serial[0] != serial[6]  # random: another seed, other goals
    answers: list[list[str]] = [[] for _ in range(4)]
    errors: list[BaseException] = []

    def client(k: int) -> None:
        try:
            for i in range(len(bodies)):
                answers[k].append(service.text(bodies[(i + k) % len(bodies)]))
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=client, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    for k in range(4):
        assert answers[k] == [serial[(i + k) % len(bodies)] for i in range(len(bodies))]
    assert [service.text(b) for b in bodies] == serial
    service.request("DELETE", "/maps/flat-2")


# ---------------------------------------------------------------------------------- bad requests


@dataclass(frozen=True)
class Case:
    """A request (:func:`_good` with ``changes``: a field set, or dropped with None; or a ``raw`` body)
    refused with ``status`` and a ``detail`` containing ``expect``; ``POST /assign`` unless ``method``
    and ``path`` say otherwise, with ``headers`` added (``Content-Type: application/json`` unless
    given)."""

    name: str
    changes: dict[str, Any]
    status: int
    expect: str
    raw: bytes | None = None
    method: str = "POST"
    path: str = "/assign"
    headers: dict[str, str] = field(default_factory=dict)


def _good() -> dict[str, Any]:
    robots = json.loads((CORPUS / "robots" / "good.json").read_text())["robots"]
    return {"map": _corpus_map(), "robots": robots, "targets": [], "method": "greedy", "seed": 0}


def _grid(**info: Any) -> dict[str, Any]:
    message = _corpus_map()
    message["info"].update(info)
    return message


def _data(values: list[Any]) -> dict[str, Any]:
    message = _corpus_map()
    message["data"] = values + message["data"][len(values) :]
    return message


CASES: list[Case] = [
    # not JSON, or not the schema: 400 / 422 naming the field
    Case("malformed-json", {}, 400, "malformed JSON", raw=b'{"map": '),
    Case("empty-body", {}, 400, "malformed JSON: the request body is empty", raw=b""),
    Case("not-utf8", {}, 400, "malformed JSON", raw=b'{"map": "\xff"}'),
    Case("not-an-object", {}, 422, "body: Input should be an object", raw=b"[1, 2]"),
    Case("unknown-field", {"robts": []}, 422, "robts: Extra inputs are not permitted"),
    Case("no-robots", {"robots": None}, 422, "robots: Field required"),
    Case("robots-not-a-list", {"robots": {"x": 1}}, 422, "robots: Input should be a valid array"),
    Case("no-map", {"map": None}, 422, "map: Field required"),
    Case("map-a-number", {"map": 3}, 422, "map: expected an OccupancyGrid object or the name of a stored map"),
    Case("seed-a-string", {"seed": "1"}, 422, "seed: Input should be a valid integer"),
    Case("seed-negative", {"seed": -1}, 422, "seed must be a non-negative integer, got -1"),
    Case("seed-fractional", {"seed": 1.5}, 422, "seed: Input should be a valid integer"),
    Case("method-a-number", {"method": 3}, 422, "method: Input should be a valid string"),
    Case("unknown-method", {"method": "teleport"}, 422, "method: unknown planner 'teleport'; known planners:"),
    Case("radius-negative", {"radius_m": -0.1}, 422, "robot.radius_m must be a positive number"),
    Case("radius-a-string", {"radius_m": "0.2"}, 422, "radius_m: Input should be a valid number"),
    # robots: the library's checks and messages (as `areasearch assign` words them)
    Case("nine-robots", {"robots": [{"x": 0.5 + 0.4 * i, "y": 1.0} for i in range(9)]}, 422,
         "request: 9 robots; the planners plan for at most 8"),
    Case("no-robot", {"robots": []}, 422, "request: 'robots' is empty; give at least one robot"),
    Case("robot-nan", {"robots": [{"x": float("nan"), "y": 1.0}]}, 422,
         "request: robots[0].x must be a finite number, got nan"),
    Case("robot-infinite", {"robots": [{"x": 1.0, "y": float("inf")}]}, 422,
         "request: robots[0].y must be a finite number, got inf"),
    Case("robot-bool", {"robots": [{"x": True, "y": 1.0}]}, 422, "request: robots[0].x must be a number, got True"),
    Case("robot-no-y", {"robots": [{"x": 1.0}]}, 422, "request: robots[0] has no 'y'"),
    Case("robot-extra-key", {"robots": [{"x": 1.0, "y": 1.0, "z": 0}]}, 422, "robots[0] has unknown field(s) 'z'"),
    Case("robot-same-id", {"robots": [{"id": "a", "x": 1.0, "y": 1.0}, {"id": "a", "x": 2.0, "y": 1.0}]}, 422,
         "request: robots id 'a' is used twice"),
    Case("robot-outside", {"robots": [{"x": 50.0, "y": 1.0}]}, 422, "robot 'robot_0' at (50, 1) lies outside the map"),
    Case("target-outside", {"targets": [{"x": 1.0, "y": -3.0}]}, 422, "target 0 at (1, -3) lies outside the map"),
    Case("target-not-an-object", {"targets": [[1, 2]]}, 422, "request: targets[0] must be an object with x, y"),
    # the map: the message's fields, then the library's checks of the values
    Case("map-no-info", {"map": {"data": []}}, 422, "map.info: Field required"),
    Case("map-width-a-string", {"map": _grid(width="80")}, 422, "map.info.width: Input should be a valid integer"),
    Case("map-width-zero", {"map": _grid(width=0)}, 422, "map.info.width: Input should be greater than or equal to 1"),
    Case("map-extra-field", {"map": {**_corpus_map(), "extra": 1}}, 422, "map.extra: Extra inputs are not permitted"),
    Case("map-data-short", {"map": _grid(width=81)}, 422, "map.data holds"),
    Case("map-data-floats", {"map": _data([0.5])}, 422, "map.data must be a list of integers"),
    Case("map-data-strings", {"map": _data(["0"])}, 422, "map.data must be a list of integers"),
    Case("map-data-not-a-list", {"map": {**_corpus_map(), "data": "AAAA"}}, 422, "map.data must be a list of integers"),
    Case("map-value-over-100", {"map": _data([0, 101])}, 422, "map: cell (iy=0, ix=1) holds 101; values must be -1"),
    Case("map-value-huge", {"map": _data([10**30])}, 422, "map.data must be a list of integers"),
    Case("map-resolution-zero", {"map": _grid(resolution=0.0)}, 422, "resolution must be in [0.001, 10.0]"),
    Case("map-resolution-nan", {"map": _grid(resolution=float("nan"))}, 422, "map: resolution must be a number"),
    Case("map-far-origin", {"map": _grid(origin={"position": {"x": 1e300, "y": 0.0}})}, 422,
         "map: origin (1e+300, 0) lies farther than 1e+07 m"),
    Case("map-rotated", {"map": _grid(origin={"position": {"x": 0.0, "y": 0.0},
                                              "orientation": {"x": 0.0, "y": 0.0, "z": 0.38, "w": 0.92}})}, 422,
         "map: origin has yaw"),
    Case("map-tilted", {"map": _grid(origin={"position": {"x": 0.0, "y": 0.0},
                                             "orientation": {"x": 0.7, "y": 0.0, "z": 0.0, "w": 0.7}})}, 422,
         "the map is tilted"),
    Case("map-no-free-cell", {"map": _data([100] * 3600)}, 422, "map: the map has no free cell"),
    Case("map-unknown-name", {"map": "nowhere"}, 422, "map: no stored map named 'nowhere'"),
    Case("map-a-path", {"map": "/etc/passwd"}, 422, "map: no stored map named '/etc/passwd'"),
    Case("map-info-a-list", {"map": {**_corpus_map(), "info": []}}, 422, "map.info: Input should be an object"),
    # huge finite numbers anywhere in the message: 422 naming the field, never an overflow
    Case("map-quaternion-1e200", {"map": _grid(origin={"position": {"x": 0.0, "y": 0.0},
                                                       "orientation": {"x": 1e200, "y": 0.0, "z": 0.0, "w": 1.0}})},
         422, "map.info.origin.orientation must be a quaternion of finite numbers, got norm 1e+200"),
    Case("map-quaternion-w-1e308", {"map": _grid(origin={"position": {"x": 0.0, "y": 0.0},
                                                         "orientation": {"w": 1e308}})},
         422, "map.info.origin.orientation must be a quaternion of finite numbers"),
    Case("map-resolution-1e300", {"map": _grid(resolution=1e300)}, 422,
         "map: resolution must be in [0.001, 10.0] metres per cell, got 1e+300"),
    Case("map-resolution-huge-int", {"map": _grid(resolution=10**400)}, 422,
         "map.info.resolution: Input should be a valid number"),
    Case("map-width-huge-int", {"map": _grid(width=10**4000, height=10**4000)}, 422,
         "map.info.width: Input should be less than or equal to 2147483647"),
    Case("robot-1e308", {"robots": [{"x": 1e308, "y": 1.0}]}, 422, "robot 'robot_0' at (1e+308, 1) lies outside"),
    Case("robot-huge-int", {"robots": [{"x": 10**400, "y": 1.0}]}, 422,
         "request: robots[0].x must be a finite number, got 1000"),
    Case("past-position-1e308", {"robots": [{"x": 0.6, "y": 1.0, "past_positions": [[1e308, 1e308]]}]}, 422,
         "past_positions[0][0] at (1e+308, 1e+308) lies outside the map"),
    Case("past-goal-huge-int", {"robots": [{"x": 0.6, "y": 1.0, "past_goals": [[0.5, -(10**400)]]}]}, 422,
         "request: robots[0].past_goals[0][1] must be a finite number"),
    Case("target-1e308", {"targets": [{"x": 1e308, "y": -1e308}]}, 422, "target 0 at (1e+308, -1e+308) lies outside"),
    Case("target-huge-int", {"targets": [{"x": 10**400, "y": 1.0}]}, 422,
         "request: targets[0].x must be a finite number"),
    Case("radius-1e308", {"radius_m": 1e308}, 422, "robot.radius_m must be a positive number of at most 5"),
    Case("sensor-range-1e308", {"sensor_range_m": 1e308}, 422,
         "camera.max_range_m must be a positive number of at most 1000"),
    # integers beyond Python's 4,300-digit conversion limit: malformed JSON, one line
    Case("seed-5000-digits", {}, 400, "malformed JSON: Invalid JSON: number out of range",
         raw=b'{"seed": ' + b"7" * 5000 + b"}"),
    Case("cell-5000-digits", {}, 400, "malformed JSON: Invalid JSON: number out of range",
         raw=json.dumps(_good()).replace('"data": [', '"data": [' + "1" * 5000 + ", ", 1).encode()),
    # stored-map names are matched whole
    Case("map-name-newline", {}, 422, "name: 'flat\\n' is not a map name", method="PUT", path="/maps/flat%0A",
         raw=json.dumps(_corpus_map()).encode()),
    Case("map-name-65", {}, 422, "is not a map name", method="PUT", path="/maps/" + "a" * 65,
         raw=json.dumps(_corpus_map()).encode()),
]  # fmt: skip


OPEN_CASES: list[Case] = [
    # without a token: what a web page could send (a CORS "simple request", DNS rebinding) is refused
    Case("text-plain", {}, 415, "send Content-Type: application/json (got 'text/plain')",
         headers={"Content-Type": "text/plain;charset=UTF-8"}),
    Case("form", {}, 415, "(got 'application/x-www-form-urlencoded')",
         headers={"Content-Type": "application/x-www-form-urlencoded"}),
    Case("multipart", {}, 415, "(got 'multipart/form-data')", headers={"Content-Type": "multipart/form-data; b=x"}),
    Case("no-content-type", {}, 415, "(got none)", headers={"Content-Type": ""}),
    Case("put-text-plain", {}, 415, "send Content-Type: application/json", method="PUT", path="/maps/x",
         headers={"Content-Type": "text/plain"}),
    Case("foreign-host", {}, 421, "Host 'evil.example:8000' is not this service",
         headers={"Host": "evil.example:8000"}),
    Case("foreign-host-get", {}, 421, "set a token to use another name", method="GET", path="/maps",
         headers={"Host": "rebind.example"}),
    Case("foreign-host-health", {}, 421, "is not this service", method="GET", path="/health",
         headers={"Host": "127.0.0.1.evil.example"}),
]  # fmt: skip
"""Refused by the ``tight`` service (no token); with a token the token guards instead."""


def _cli_cases() -> list[tuple[str, str, str]]:
    """(option, corpus file, expected text) of the CLI corpus's ``assign`` rows that change the robots
    or targets file to one that parses (``tests/test_bad_inputs.py``): the service must refuse the same
    lists with the same words."""
    sys.path.insert(0, str(TESTS))
    try:
        from test_bad_inputs import CASES as CLI_CASES
    finally:
        sys.path.remove(str(TESTS))
    rows = []
    for case in CLI_CASES:
        if case.command != "assign" or len(case.changes) != 1:
            continue
        ((option, value),) = case.changes.items()
        if option not in ("--robots", "--targets") or not isinstance(value, str) or not value.startswith("{in}/"):
            continue
        path = CORPUS / value.removeprefix("{in}/")
        try:
            doc = json.loads(path.read_text())
        except (OSError, ValueError):  # JSONDecodeError, or an integer beyond 4,300 digits
            continue  # a file that is not JSON: the service's 400, above
        key = option.strip("-")
        if isinstance(doc, dict) and set(doc) == {key}:
            rows.append((option, value.removeprefix("{in}/"), case.expect))
    return rows


CLI_ROWS = _cli_cases()


def _body(case: Case) -> bytes:
    if case.raw is not None:
        return case.raw
    body = _good()
    for key, value in case.changes.items():
        if value is None:
            body.pop(key, None)
        else:
            body[key] = value
    return json.dumps(body).encode()


def _refused(service: Service, case: Case) -> None:
    body = _body(case) if case.method in ("POST", "PUT") else None
    status, doc = service.request(case.method, case.path, raw=body, headers=case.headers)
    assert status == case.status, doc
    assert isinstance(doc, dict) and set(doc) == {"detail"}, doc
    detail = doc["detail"]
    assert case.expect in detail and "\n" not in detail and "Traceback" not in detail and len(detail) <= 600, detail


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_a_bad_request_is_one_clear_refusal(service: Service, case: Case) -> None:
    _refused(service, case)


@pytest.mark.parametrize("case", OPEN_CASES, ids=lambda c: c.name)
def test_without_a_token_what_a_web_page_sends_is_refused(tight: Service, case: Case) -> None:
    _refused(tight, case)


def test_without_a_token_local_hosts_and_json_are_served(tight: Service) -> None:
    for host in ("localhost", "localhost:8000", "127.0.0.1", f"127.0.0.1:{tight.port}", "[::1]:8000", "::1",
                 "10.1.2.3:80", "robot.localhost:8000", "LOCALHOST"):  # fmt: skip
        status, doc = tight.request("GET", "/maps", headers={"Host": host})
        assert status == 200, (host, doc)
    body = {"map": _room(), "robots": [{"x": 1.05, "y": 1.55}]}
    status, doc = tight.request("POST", "/assign", body, headers={"Content-Type": "application/json; charset=utf-8"})
    assert status == 200, doc
    assert tight.request("GET", "/health", headers={"Host": "evil.example"})[0] == 421


def test_with_a_token_the_token_guards_instead_of_host_and_content_type(service: Service) -> None:
    status, doc = service.request("POST", "/assign", _good(), headers={"Content-Type": "text/plain", "Host": "x.y"})
    assert status == 200, doc  # a web page cannot send the token: Host and Content-Type need no check
    assert service.request("POST", "/assign", _good(), token=None, headers={"Host": "x.y"})[0] == 401


def test_the_cli_corpus_is_refused_with_the_cli_words(service: Service) -> None:
    assert len(CLI_ROWS) >= 10
    for option, name, expect in CLI_ROWS:
        body = _good()
        key = option.strip("-")
        body[key] = json.loads((CORPUS / name).read_text())[key]
        status, doc = service.request("POST", "/assign", body)
        assert status == 422, (name, doc)
        assert doc["detail"].startswith("request: ") or doc["detail"].startswith(("robot ", "target ")), doc
        assert expect in doc["detail"], (name, doc["detail"])
    assert "Traceback" not in service.log()


def test_the_good_request_works_and_dropped_targets_are_listed(service: Service) -> None:
    body = _good()
    status, doc = service.request("POST", "/assign", body)
    assert status == 200 and [r["id"] for r in doc["robots"]] == ["a", "b"]
    body["map"] = grid_message(load_occupancy(CORPUS / "ros" / "thick.yaml"))
    body["targets"] = json.loads((CORPUS / "robots" / "targets_dropped.json").read_text())["targets"]
    status, doc = service.request("POST", "/assign", body)
    assert status == 200, doc
    reasons = {d["id"]: d["reason"] for d in doc["dropped_targets"]}
    assert reasons == {"wall": "in a wall", "pocket": "unreachable", "behind": "in unknown space"}


@pytest.mark.slow  # six processes, two of them start a worker
def test_bad_command_lines_are_refused(tmp_path: Path, run_cli: CliRunner) -> None:
    for args, expect in (
        (["--method", "teleport"], "unknown planner 'teleport'"),
        (["--workers", "0"], "argument --workers: expected a positive integer"),
        (["--time-limit-s", "0"], "time_limit_s must be a number of seconds in (0, 86400]"),
        (["--port", "70000"], "port must be an integer from 0 to 65535"),
        (["--max-map-cells", "99999999999"], "over the library's limit"),
        (["--idle-timeout-s", "0"], "idle_timeout_s must be a number of seconds in (0, 3600]"),
        (["--header-timeout-s", "nan"], "header_timeout_s must be a number of seconds in (0, 3600], got nan"),
        (["--max-connections", "0"], "argument --max-connections: expected a positive integer"),
        (["--max-connections", "20000"], "max_connections must be at most 10000, got 20000"),
        (["--set", "candidates.distance_cell_m=3"], "candidates.distance_cell_m must be a number from 0 to 1"),
        (["--set", "robot.radius_m=0.3"], "not allowed here; use --radius-m"),
        (["--method", "ncm-untrained", "--weights", str(tmp_path / "absent")], "absent.json: cannot read the policy"),
    ):
        port = [] if "--port" in args else ["--port", "0"]
        result = run_cli("serve", *port, *args, timeout=300)
        assert result.returncode == 2, (args, result.stderr)
        last = result.stderr.strip().splitlines()[-1]
        assert last.startswith(("areasearch: error:", "areasearch serve: error:")) and expect in last, result.stderr
        assert "Traceback" not in result.stderr


# ---------------------------------------------------------------------------------- limits


def test_a_large_body_or_map_is_413(tight: Service) -> None:
    big = b"x" * 16_000_001
    status, doc = tight.request("POST", "/assign", raw=big)
    assert status == 413 and "over the limit of 16,000,000 bytes" in doc["detail"]
    # a chunked body (no Content-Length): refused as soon as it passes the limit
    with socket.create_connection((tight.host, tight.port), timeout=60) as sock:
        sock.sendall(
            b"PUT /maps/x HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
            b"Transfer-Encoding: chunked\r\n\r\n"
        )
        chunk = b"%x\r\n%s\r\n" % (2**20, b"1" * 2**20)
        try:
            for _ in range(20):
                sock.sendall(chunk)
        except OSError:
            pass  # the service answered and closed
        reply = sock.recv(65536).decode(errors="replace")
    assert reply.startswith("HTTP/1.1 413"), reply
    message = _grid(width=3000, height=2000)
    status, doc = tight.request("PUT", "/maps/huge", message)
    assert (
        status == 413 and "3000 x 2000 = 6,000,000 cells, more than the service's limit of 4,500,000" in doc["detail"]
    )
    status, doc = tight.request("POST", "/assign", {"map": message, "robots": [{"x": 1.0, "y": 1.0}]})
    assert status == 413


def _closed_after(sock: socket.socket, limit: float) -> tuple[float, bytes]:
    """(seconds until the service closed ``sock``, what it sent before), reading at most ``limit`` s."""
    t0 = time.monotonic()
    sock.settimeout(0.2)
    received = b""
    while time.monotonic() - t0 < limit:
        try:
            chunk = sock.recv(65536)
        except TimeoutError:
            continue
        except ConnectionResetError:
            break
        if not chunk:
            break
        received += chunk
    else:
        raise AssertionError(f"still open after {limit} s; received {received[:200]!r}")
    return time.monotonic() - t0, received


@pytest.mark.slow  # waits for the deadlines: about 6 s, and 15 s for the 10 s body deadline of `service`
@pytest.mark.parametrize("which", ["service", "tight"])
def test_idle_slow_head_and_slow_body_connections_are_closed(request: pytest.FixtureRequest, which: str) -> None:
    """Both services: --idle-timeout-s 2, --header-timeout-s 1; the token (``service``) is never reached."""
    svc: Service = request.getfixturevalue(which)
    address = (svc.host, svc.port)
    with socket.create_connection(address, timeout=10) as sock:  # connects, sends nothing
        took, received = _closed_after(sock, 8)
    assert 1.5 < took < 5 and received == b"", (took, received)
    with socket.create_connection(address, timeout=10) as sock:  # a head a byte every 0.2 s
        t0 = time.monotonic()
        with pytest.raises(OSError):
            for byte in b"GET /maps HTTP/1.1\r\nHost: localhost\r\nX-Slow: " + b"s" * 100:
                sock.sendall(bytes([byte]))
                time.sleep(0.2)
                assert time.monotonic() - t0 < 8, "a slow head was never cut off"
        assert time.monotonic() - t0 < 4
    with socket.create_connection(address, timeout=10) as sock:  # an answer, then nothing: keep-alive ends
        sock.sendall(b"GET /health HTTP/1.1\r\nHost: localhost\r\n\r\n")
        took, received = _closed_after(sock, 8)
    assert received.startswith(b"HTTP/1.1 200") and 1.5 < took < 5, (took, received[:100])
    auth = f"Authorization: Bearer {svc.token}\r\n".encode() if svc.token else b""
    with socket.create_connection(address, timeout=10) as sock:  # a body that never comes whole
        sock.sendall(b"PUT /maps/slow HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
                     + auth + b"Content-Length: 1000\r\n\r\n{")  # fmt: skip
        took, received = _closed_after(sock, 40)
    limit = 10.0 if svc.token else 0.5  # --time-limit-s
    assert received.startswith(b"HTTP/1.1 408") and b"connection: close" in received.lower(), received[:300]
    assert took < limit + 3, took
    assert "Traceback" not in svc.log()


def test_after_an_early_answer_the_body_still_has_its_deadline(tight: Service) -> None:
    """A 415 before the body is read; the rest of the body is dropped as it comes, until the body's
    deadline (--time-limit-s 0.5, and a second): a body that never ends is cut there."""
    with socket.create_connection((tight.host, tight.port), timeout=10) as sock:
        sock.sendall(b"PUT /maps/x HTTP/1.1\r\nHost: localhost\r\nContent-Length: 100000\r\n\r\n{")
        took, received = _closed_after(sock, 10)
    assert received.startswith(b"HTTP/1.1 415") and took < 4, (took, received[:200])


def test_open_connections_are_bounded(tight: Service) -> None:
    """--max-connections 8: beyond it a connection is answered 503 and closed when accepted."""
    socks = [socket.create_connection((tight.host, tight.port), timeout=10) for _ in range(TIGHT_CONNECTIONS + 3)]
    try:
        time.sleep(0.3)
        answered = []
        for sock in socks:
            sock.setblocking(False)
            try:
                answered.append(sock.recv(65536))
            except BlockingIOError:
                answered.append(b"")  # accepted and held open
        refused = [a for a in answered if a]
        assert len(refused) >= 3 and answered.count(b"") <= TIGHT_CONNECTIONS, answered
        for reply in refused:
            assert reply.startswith(b"HTTP/1.1 503") and b"connection: close" in reply, reply
            assert b"more than 8 open connections (--max-connections)" in reply, reply
    finally:
        for sock in socks:
            sock.close()
    end = time.monotonic() + 10
    while tight.request("GET", "/health")[0] != 200:  # the slots come free as the sockets close
        assert time.monotonic() < end
        time.sleep(0.1)


def test_a_huge_content_length_is_a_400(tight: Service) -> None:
    """An integer beyond Python's 4,300-digit conversion limit in a header: one line, never a 500."""
    with socket.create_connection((tight.host, tight.port), timeout=10) as sock:
        sock.sendall(b"POST /assign HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
                     b"Content-Length: " + b"9" * 5000 + b"\r\n\r\n{}")  # fmt: skip
        _, received = _closed_after(sock, 5)
    assert received.startswith(b"HTTP/1.1 400"), received[:200]


def test_a_request_over_the_time_limit_is_stopped(tight: Service) -> None:
    assert tight.request("PUT", "/maps/big", _big())[0] == 201
    (before,) = tight.worker_pids()
    t0 = time.monotonic()
    status, doc = tight.request("POST", "/assign", {"map": "big", "robots": EIGHT})
    assert status == 504 and "longer than the time limit of 0.5 s" in doc["detail"], doc
    assert time.monotonic() - t0 < 5
    assert f"worker {before} stopped (time limit)" in tight.log()
    assert not Path(f"/proc/{before}").exists() or before not in tight.worker_pids()  # killed, not left running
    tight.wait_idle(1)
    assert before not in tight.worker_pids()
    status, doc = tight.request("POST", "/assign", {"map": _room(), "robots": [{"x": 1.05, "y": 1.55}]})
    assert status == 200, doc  # the fresh worker answers


def _exited(pid: int) -> bool:
    """Whether process ``pid`` has ended (gone, or a zombie not yet reaped)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


@pytest.mark.slow  # two workers killed and warmed again: several seconds
def test_a_worker_that_died_while_idle_is_replaced_never_a_500(service: Service) -> None:
    service.wait_idle(2)
    body = {"map": _room(), "robots": [{"x": 1.05, "y": 1.55}]}
    expected = service.text(body)
    for wait in (False, True):  # the request at once (meets the dead worker), or after its end is seen
        victims = service.worker_pids()
        assert len(victims) == 2
        for pid in victims:
            os.kill(pid, signal.SIGKILL)
        end = time.monotonic() + 10
        while not all(_exited(pid) for pid in victims):
            assert time.monotonic() < end
            time.sleep(0.01)
        if wait:
            time.sleep(1.0)
        status, doc = service.request("POST", "/assign", body)
        assert status == 200 and doc == json.loads(expected), (status, doc)
        assert not victims & service.worker_pids()
        service.wait_idle(2)
    assert service.log().count("(it ended while idle") >= 4, service.log()[-3000:]
    assert "Traceback" not in service.log() and " 500 " not in service.log()


def test_a_client_that_leaves_stops_its_work(service: Service) -> None:
    """Last of the module's service tests: it replaces one of its workers."""
    assert service.request("PUT", "/maps/big", _big())[0] == 201
    service.wait_idle(2)
    before = service.worker_pids()
    request = json.dumps({"map": "big", "robots": EIGHT}).encode()
    with socket.create_connection((service.host, service.port), timeout=60) as sock:
        sock.sendall(
            b"POST /assign HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            + f"Authorization: Bearer {TOKEN}\r\nContent-Length: {len(request)}\r\n\r\n".encode()
            + request
        )
        time.sleep(0.3)  # the work has started; then the client hangs up
    end = time.monotonic() + 30
    while "stopped (client disconnected)" not in service.log() and time.monotonic() < end:
        time.sleep(0.05)
    found = re.search(r"worker (\d+) stopped \(client disconnected\)", service.log())
    assert found, service.log()[-3000:]
    gone = int(found.group(1))
    assert gone in before
    end = time.monotonic() + 10
    while Path(f"/proc/{gone}").exists() and gone in service.worker_pids() and time.monotonic() < end:
        time.sleep(0.05)
    assert gone not in service.worker_pids()
    service.wait_idle(2)
    assert service.request("GET", "/health", token=None)[1]["status"] == "ready"
    status, _ = service.request("POST", "/assign", {"map": _room(), "robots": [{"x": 1.05, "y": 1.55}]})
    assert status == 200
    assert "Traceback" not in service.log()


def test_the_routes_dependencies_and_refusals_are_plain_functions() -> None:
    """The token and the map name are FastAPI dependencies, a body's refusal one line from pydantic's
    errors; each callable without a server."""
    import asyncio

    from fastapi.security import HTTPAuthorizationCredentials

    from areasearch.service.app import Service, map_name, public, require_token, router
    from areasearch.service.pool import WorkerPool
    from areasearch.service.schema import AssignRequest, Problem, read_json, validation_problem
    from areasearch.service.settings import ServeConfig

    paths = {route.path for route in [*public.routes, *router.routes]}  # type: ignore[attr-defined]
    assert {"/health", "/methods", "/assign", "/maps", "/maps/{name}", "/openapi.json", "/docs"} <= paths
    config = ServeConfig(token=TOKEN)
    service = Service(config, WorkerPool(config, lambda _: None))
    asyncio.run(require_token(service, HTTPAuthorizationCredentials(scheme="Bearer", credentials=TOKEN)))
    for sent in (None, HTTPAuthorizationCredentials(scheme="Bearer", credentials="wrong")):
        with pytest.raises(Problem) as refused:
            asyncio.run(require_token(service, sent))
        assert refused.value.status_code == 401 and refused.value.headers == {"www-authenticate": "Bearer"}
    open_service = Service(ServeConfig(), WorkerPool(ServeConfig(), lambda _: None))
    asyncio.run(require_token(open_service, None))  # no token set: nothing wanted
    assert map_name("flat-1") == "flat-1"
    with pytest.raises(Problem, match="is not a map name"):
        map_name("flat\n")
    with pytest.raises(Problem, match="malformed JSON: the request body is empty"):
        read_json(b"")
    with pytest.raises(Problem, match="malformed JSON: Invalid JSON: EOF while parsing"):
        read_json(b'{"map": ')
    try:
        AssignRequest.model_validate({"robts": [], "seed": "1"})
    except ValidationError as exc:
        problem = validation_problem(exc.errors())
    assert (problem.status_code, problem.detail) == (422, "map: Field required (and 3 more)")


def test_the_message_reader_refuses_what_the_library_refuses() -> None:
    message = _room()
    message["data"][5] = -2
    with pytest.raises(MapError, match=r"map: cell \(iy=0, ix=5\) holds -2"):
        grid_cells(OccupancyGrid.model_validate(message))
    message = _room()
    message["info"].update(width=2, height=2)
    message["data"] = [0, 0, 0, 0]
    with pytest.raises(MapError, match="at least 3x3 cells"):
        grid_cells(OccupancyGrid.model_validate(message))
    ros1 = _room()
    ros1["info"]["origin"]["orientation"] = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 0.0}  # ROS 1's unset quaternion
    ros1["header"] = {"seq": 3, "stamp": {"secs": 1, "nsecs": 2}, "frame_id": "map"}
    ros1["info"]["map_load_time"] = {"secs": 0, "nsecs": 0}
    assert grid_cells(OccupancyGrid.model_validate(ros1)).origin_xy == (0.0, 0.0)


# ---------------------------------------------------------------------------------- any body at all

_JSON = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=10), inner, max_size=5),
    max_leaves=20,
)
_FIELDS = ["map", "robots", "targets", "method", "seed", "radius_m", "sensor_range_m", "extra"]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    changes=st.dictionaries(st.sampled_from(_FIELDS), _JSON, max_size=3),
    robot=st.dictionaries(st.sampled_from(["id", "x", "y", "yaw", "past_positions", "past_goals", "z"]), _JSON),
    info=st.dictionaries(st.sampled_from(["resolution", "width", "height", "origin"]), _JSON, max_size=2),
)
def test_any_body_gets_an_answer_never_an_internal_error(
    service: Service, changes: dict[str, Any], robot: dict[str, Any], info: dict[str, Any]
) -> None:
    """A good request with random JSON in some fields, a random robot and random map fields: 200 or
    one 4xx line, never a 500 (the request schema's property test)."""
    body = _good()
    body.update(changes)
    body["robots"] = [*_good()["robots"][:1], robot]
    if isinstance(body["map"], dict) and info:
        body["map"] = _grid(**info)
    status, doc = service.request("POST", "/assign", raw=json.dumps(body).encode())
    assert status in (200, 400, 413, 422), (status, doc)
    if status != 200:
        assert set(doc) == {"detail"} and "\n" not in doc["detail"] and len(doc["detail"]) <= 600, doc
