"""``areasearch serve``: the goal planners as a long-running HTTP JSON service for robot stacks.

A robot stack that runs SLAM wants a goal per robot every few seconds, from any language. A fresh
``areasearch assign`` process pays 3-7 s of start-up per call (numba's kernels, PyTorch, the
network); the library call itself is 100-150 ms on a large map. The service pays the start-up once
and then answers over HTTP:

``POST /assign``
    ``{"map": <OccupancyGrid> | "<stored name>", "robots": [...], "targets": [...], "method": "greedy",
    "seed": 0}``; ``robots`` and ``targets`` exactly as in ``areasearch assign``'s ``robots.json`` /
    ``targets.json``, optional ``radius_m`` and ``sensor_range_m`` as its options. The answer is
    byte for byte the JSON ``areasearch assign`` prints. The map is a ROS ``nav_msgs/OccupancyGrid``
    as rosbridge serialises it (:mod:`areasearch.service.occupancy_msg`: row 0 at the origin).
``PUT /maps/{name}`` (same map body), ``GET /maps``, ``DELETE /maps/{name}``
    maps kept by the service, so that a large map is sent once per update and each call sends poses.
``GET /health``
    ``{"status": "ready"}`` (200) once every worker has loaded the planners and warmed the kernels,
    ``{"status": "starting"}`` (503) before; never needs the token.
``GET /methods``
    the registered planners with their origin (built-in, shipped policy, plug-in: the rows of
    ``areasearch methods``), and the default method's ``--weights`` with their SHA-256, which the
    answers of that method name too. ``/openapi.json`` and ``/docs``:
    FastAPI's schema and interactive docs.

Architecture: one uvicorn process runs the HTTP side (FastAPI, one asyncio event loop: parsing,
checking, the stored maps) and hands each assignment to one of ``--workers N`` **worker
processes**. Each worker is started with the service, loads every learned planner, runs every
planner once on a small map (numba's kernels, the networks' first calls) and only then counts as
ready; it plans one request at a time, so that no two requests ever share planner or world state
(classical and plug-in planners are built afresh for each request, a plug-in that fails at start-up
is left out and answered 422; a learned planner's network is loaded once
and is stateless between calls; every draw comes from ``np.random.default_rng(seed)``: same
request and seed, same answer, whatever other clients do). N processes rather than uvicorn workers
or threads because (1) the work is CPU-bound NumPy / numba / PyTorch, so N requests in parallel
need N processes; (2) stored maps live in the one HTTP process, so every worker sees every ``PUT``;
(3) a request over the time limit, or whose client hung up, is stopped by killing its worker
process (the only way to stop a numba kernel mid-run) and starting a warm replacement, without
touching the other requests. Workers talk to the HTTP process over their stdin / stdout: a
length-prefixed JSON header and the map's raw int8 cells, never pickle; a worker first answers
"taken" to each frame, so that a request sent to a worker that had died while idle (killed, out of
memory) goes to another worker, never a 500 (an idle worker's death is also seen at once, and it is
replaced). A worker keeps the last few maps it planned on (by a hash of their cells), so a map is
sent to a worker once, not every call.

Bad requests: malformed JSON is 400; a body that does not fit the schema, or that the library
refuses (robots outside the map or in a wall, NaN poses, an unknown method, more than 8 robots...)
is 422 with one line naming the field, the library's own :class:`~areasearch.errors.MapError` /
:class:`~areasearch.errors.ConfigError` message for what the library checks; a body over
``max_body_bytes`` or a map over ``max_map_cells`` is 413; a request over ``time_limit_s`` is 504
(503 when no worker came free in time); an internal error is a one-line 500, its traceback in the
server's log only. No path from a request is ever opened (stored maps are names in a dict); the
service binds 127.0.0.1 unless told otherwise; with a token (``--token`` or
``AREASEARCH_SERVE_TOKEN``) every endpoint but ``/health`` wants ``Authorization: Bearer <token>``;
without one, a ``Host`` other than an IP address, ``localhost`` or ``--host`` is 421 and a body
other than ``application/json`` 415 (what a web page could send: :class:`Guard`). Every
connection has a deadline in each phase and their number a bound (:class:`Connection`).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import hashlib
import hmac
import ipaddress
import json
import logging
import math
import os
import re
import socket
import struct
import sys
import time
import traceback
from collections import OrderedDict
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass, field
from typing import Annotated, Any

import h11
import numpy as np
import orjson
from fastapi import FastAPI, Request
from fastapi.openapi.utils import get_openapi
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, ConfigDict, ValidationError, WithJsonSchema
from pydantic_core import from_json
from uvicorn.protocols.http.h11_impl import H11Protocol

from ..errors import AreaSearchError, ConfigError
from ..inputs import LIMIT_VARIABLES, clip, limits, short
from ..planners import LEARNED, PLANNERS, check_takes_weights, describe_planners, make_planner
from .occupancy_msg import GridCells, OccupancyGrid, grid_cells

log = logging.getLogger("uvicorn.error")

TOKEN_VARIABLE = "AREASEARCH_SERVE_TOKEN"
"""Environment variable holding the bearer token (rather than ``--token``, which ``ps`` shows)."""

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
"""A stored map's name: letters, digits, ``_ . -``, at most 64 characters (a key, never a path); matched
whole (``NAME.fullmatch``: ``$`` alone would let a trailing newline through)."""

WORKER_MAPS = 4
"""Maps a worker keeps read (least recently used dropped first)."""


# ---------------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class ServeConfig:
    """Settings of ``areasearch serve``: where it listens, what it plans with, its limits."""

    host: str = "127.0.0.1"
    """Address to bind; 127.0.0.1 (this machine only) unless told otherwise."""
    port: int = 8000
    """TCP port; 0 picks a free one (printed at start-up)."""
    method: str = "greedy"
    """Planner of a request that names none."""
    weights: str | None = None
    """A learned planner's ``PREFIX.safetensors`` + ``PREFIX.json`` for ``method`` (read at start-up)."""
    workers: int = 1
    """Worker processes planning in parallel (one request each at a time; about one CPU core and
    300-400 MB of memory each)."""
    token: str | None = None
    """Bearer token wanted on every endpoint but ``/health``; None: no token."""
    time_limit_s: float = 30.0
    """Most seconds a request may take (waiting for a worker included, and receiving the body);
    past it the request gets 504 (503 when still waiting for a worker) and its worker is replaced."""
    max_body_bytes: int = 64 * 2**20
    """Largest request body; a larger one gets 413 before it is read. The largest bundled map
    (3.3 M cells) is about 10 MB as an OccupancyGrid JSON."""
    max_map_cells: int = field(default_factory=lambda: limits().max_map_cells)
    """Largest map, width x height cells (413 above); at most the library's
    ``AREASEARCH_MAX_MAP_CELLS`` (25,000,000 by default)."""
    max_maps: int = 16
    """Most maps stored by ``PUT /maps/{name}`` at once (each one byte a cell in memory)."""
    max_connections: int = 64
    """Most connections open at once; one more is answered 503 and closed as soon as it is accepted
    (each open connection holds a file descriptor, whatever it sends)."""
    idle_timeout_s: float = 30.0
    """A connection with no request under way (just opened, or answered) is closed after this long
    without a byte."""
    header_timeout_s: float = 10.0
    """Most seconds from a request's first byte to the end of its head (request line and headers);
    the body then has ``time_limit_s``. Both before the token is checked."""

    def validate(self) -> ServeConfig:
        def positive_int(name: str, value: Any, low: int = 1) -> None:
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ConfigError(f"{name} must be an integer >= {low}, got {short(value)}")

        if not isinstance(self.host, str) or not self.host:
            raise ConfigError(f"host must be an address, got {short(self.host)}")
        if isinstance(self.port, bool) or not isinstance(self.port, int) or not 0 <= self.port <= 65535:
            raise ConfigError(f"port must be an integer from 0 to 65535, got {short(self.port)}")
        positive_int("workers", self.workers)
        if self.workers > 64:
            raise ConfigError(f"workers must be at most 64, got {self.workers}")
        positive_int("max_body_bytes", self.max_body_bytes, 1024)
        positive_int("max_maps", self.max_maps)
        positive_int("max_map_cells", self.max_map_cells, 9)
        library = limits().max_map_cells
        if self.max_map_cells > library:
            raise ConfigError(
                f"max_map_cells {self.max_map_cells:,} is over the library's limit of {library:,} "
                f"(environment variable {LIMIT_VARIABLES['max_map_cells']})"
            )
        for name, t, high in (("time_limit_s", self.time_limit_s, 86400), ("idle_timeout_s", self.idle_timeout_s, 3600),
                              ("header_timeout_s", self.header_timeout_s, 3600)):  # fmt: skip
            if isinstance(t, bool) or not isinstance(t, (int, float)) or not (math.isfinite(t) and 0 < t <= high):
                raise ConfigError(f"{name} must be a number of seconds in (0, {high}], got {short(t)}")
        positive_int("max_connections", self.max_connections)
        if self.max_connections > 10000:
            raise ConfigError(f"max_connections must be at most 10000, got {self.max_connections}")
        if self.token is not None and (not self.token or not self.token.isprintable() or " " in self.token):
            raise ConfigError("token must be a non-empty string of printable characters without spaces")
        if self.weights is not None and (not isinstance(self.weights, str) or not self.weights):
            raise ConfigError("weights must be a path prefix (PREFIX.safetensors + PREFIX.json)")
        check_method(self.method, self.weights)
        if self.weights is not None:
            check_takes_weights(self.method)  # weights for a planner that takes none: one clear error
        return self


def check_method(name: Any, weights: str | None = None) -> str:
    """``name`` when it is a registered planner (or a learned method that ``weights`` of your own
    play); else make_planner's own ConfigError."""
    if not isinstance(name, str):
        raise ConfigError(f"method must be a planner name, got {short(name)}")
    if name not in PLANNERS and not (weights and name in LEARNED):
        make_planner(name)  # raises the library's message (unknown, or a policy not shipped)
    return name


# ---------------------------------------------------------------------------------- request bodies

_POINT = {"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 2}
ROBOT_SCHEMA = {
    "type": "object",
    "properties": {
        "id": {"type": "string", "minLength": 1},
        "x": {"type": "number"},
        "y": {"type": "number"},
        "yaw": {"type": "number", "default": 0.0},
        "past_positions": {"type": "array", "items": _POINT, "description": "newest first"},
        "past_goals": {"type": "array", "items": {"anyOf": [_POINT, {"type": "null"}]}, "description": "newest first"},
    },
    "required": ["x", "y"],
    "additionalProperties": False,
}
TARGET_SCHEMA = {
    "type": "object",
    "properties": {"id": {"type": "string", "minLength": 1}, "x": {"type": "number"}, "y": {"type": "number"}},
    "required": ["x", "y"],
    "additionalProperties": False,
}


class AssignRequest(BaseModel):
    """``POST /assign``. The map is an OccupancyGrid or a stored map's name; ``robots`` and
    ``targets`` are checked by :func:`areasearch.service.assign.robots_from_json` / ``targets_from_json``
    (the messages of ``areasearch assign``), the rest by the schema."""

    model_config = ConfigDict(strict=True, extra="forbid")

    map: Annotated[
        Any,
        WithJsonSchema(
            {
                "anyOf": [
                    {"type": "object", "description": "a nav_msgs/OccupancyGrid, as rosbridge serialises it"},
                    {"type": "string", "pattern": NAME.pattern, "description": "a map stored by PUT /maps/{name}"},
                ]
            }
        ),
    ]
    robots: Annotated[list[Any], WithJsonSchema({"type": "array", "items": ROBOT_SCHEMA, "minItems": 1})]
    targets: Annotated[list[Any], WithJsonSchema({"type": "array", "items": TARGET_SCHEMA})] = []
    method: str | None = None
    seed: int = 0
    radius_m: float | None = None
    sensor_range_m: float | None = None


class Problem(Exception):
    """A request refused: HTTP ``status`` and a one-line ``detail``."""

    def __init__(self, status: int, detail: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = " ".join(detail.split())
        self.headers = headers


def _where(loc: tuple[Any, ...], prefix: str) -> str:
    text = prefix
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else str(part)
    return text or "body"


JSON_WORDS = {
    "list_type": "Input should be a valid array",
    "dict_type": "Input should be an object",
    "model_type": "Input should be an object",
}
"""Messages of the pydantic errors that Python-mode validation words in Python's terms ("a valid list",
"a valid dictionary or instance of Pose"), in the terms of the JSON a client sent."""


def _schema_problem(exc: ValidationError, prefix: str = "") -> Problem:
    """400 for JSON that does not parse, else 422 naming the first field at fault (and how many more)."""
    errors = exc.errors(include_url=False, include_context=False, include_input=False)
    if any(e["type"] == "json_invalid" for e in errors):
        return Problem(400, f"malformed JSON: {clip(errors[0]['msg'])}")
    first = errors[0]
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    words = JSON_WORDS.get(first["type"], first["msg"])
    return Problem(422, f"{_where(tuple(first['loc']), prefix)}: {clip(words)}{more}")


def _loads(body: bytes) -> Any:
    """The JSON value of ``body``: orjson's parse (3-4 x faster than pydantic-core's on a medium
    map's cell list), or, for a body orjson refuses or reads otherwise, pydantic-core's ``from_json``
    (the rules of ``model_validate_json``): NaN and Infinity are numbers there, for the library to
    refuse by name; integers are exact up to Python's 4,300 digits ("number out of range" beyond),
    where orjson reads one beyond 64 bits as a float (of the integer fields, only ``seed`` can be
    that large and valid). ValueError for what is not JSON."""
    try:
        value = orjson.loads(body)
    except orjson.JSONDecodeError:
        return from_json(body)
    if isinstance(value, dict) and isinstance(value.get("seed"), float):
        return from_json(body)
    return value


def _parse_json(model: type[BaseModel], body: bytes, prefix: str = "") -> Any:
    """``body`` as a ``model``: 400 when it is not JSON, 422 naming the field that does not fit.

    Parsed by :func:`_loads`, validated in Python mode: ``model_validate_json`` parses with its own
    parser and then copies the map's ``data`` (3.3 M cells on the largest bundled map) into Python
    objects (``benchmarks/bench_serve_parse.py``); the map's cells are then converted in one C pass
    (:func:`~areasearch.service.occupancy_msg.grid_cells`)."""
    if not body:
        raise Problem(400, "malformed JSON: the request body is empty")
    try:
        value = _loads(body)
    except ValueError as exc:
        raise Problem(400, f"malformed JSON: Invalid JSON: {clip(str(exc))}") from None
    except RecursionError:
        raise Problem(400, "malformed JSON: nested too deeply") from None
    try:
        return model.model_validate(value)
    except ValidationError as exc:
        raise _schema_problem(exc, prefix) from None


def _read_grid(value: Any, source: str, max_cells: int) -> GridCells:
    """An OccupancyGrid body (parsed JSON) as checked cells: 422 for a field or value at fault, 413
    for more cells than ``max_cells``."""
    if isinstance(value, OccupancyGrid):
        msg = value
    else:
        try:
            msg = OccupancyGrid.model_validate(value)
        except ValidationError as exc:
            raise _schema_problem(exc, source) from None
    cells = msg.info.width * msg.info.height  # each side at most 2**31 - 1 (the schema): a printable product
    if cells > max_cells:
        raise Problem(
            413,
            f"{source}: {msg.info.width} x {msg.info.height} = {cells:,} cells, more than the service's limit "
            f"of {max_cells:,} (--max-map-cells)",
        )
    try:
        return grid_cells(msg, source)
    except AreaSearchError as exc:
        raise Problem(422, str(exc)) from None


# ---------------------------------------------------------------------------------- worker processes
#
# Frame: "<IQ" (header length, payload length), a JSON header (UTF-8), the payload (raw bytes).


def _frame(header: dict[str, Any], payload: bytes = b"") -> bytes:
    head = json.dumps(header).encode()
    return struct.pack("<IQ", len(head), len(payload)) + head + payload


def _map_header(grid: GridCells, key: str) -> dict[str, Any]:
    h, w = grid.cells.shape
    return {"key": key, "height": h, "width": w, "resolution": grid.resolution, "origin": list(grid.origin_xy),
            "source": grid.source}  # fmt: skip


def _warm_map() -> GridCells:
    """A small room, half of it known: frontiers, a target, two robots (the kernels' warm-up)."""
    cells = np.full((30, 60), -1, dtype=np.int8)
    cells[:, :30] = 0
    cells[[0, -1], :] = 100
    cells[:, [0, -1]] = 100
    return GridCells(cells, 0.1, (0.0, 0.0), "warm-up")


def worker_main(settings: dict[str, Any]) -> None:
    """A worker process: load and warm the planners, then plan one framed request at a time from stdin,
    answering on stdout, until stdin closes (the service stopped, or died)."""
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything printed by a library goes to the log, never into the frames
    inp = sys.stdin.buffer

    def read_exactly(n: int) -> bytes:
        data = inp.read(n) if n else b""
        if len(data) != n:
            raise EOFError
        return data

    def send(header: dict[str, Any], payload: bytes = b"") -> None:
        out.write(_frame(header, payload))
        out.flush()

    from ..planners.learned import LearnedPlanner
    from .assign import assign_goals, assignments_json, dumps, robots_from_json, targets_from_json

    try:
        import torch

        torch.set_num_threads(1)
        started = time.perf_counter()
        learned: dict[str, Any] = {}
        """Planners built once and kept: the learned networks, and the default method with --weights."""
        broken: dict[str, str] = {}
        """Plug-ins that fail to build or to plan on the warm-up map: answered 422 with the message."""
        warm = _warm_map().to_map()
        poses = [(1.05, 1.55, 0.0), (1.05, 0.75, 1.0)]
        default, weights = settings["method"], settings.get("weights")
        plugins = list(PLANNERS.discovery().plugins)
        own_only = [] if default in PLANNERS.builtins or default in plugins else [default]  # a policy not shipped
        for name in [*PLANNERS.builtins, *own_only, *plugins]:
            try:
                planner = make_planner(name, weights=weights if name == default else None)
                assign_goals(warm, poses, planner, targets=[(2.0, 1.5)])
            except Exception as exc:  # a plug-in may raise anything; the built-ins and the default must work
                if name not in plugins or name == default:
                    raise
                broken[name] = " ".join(str(exc).split()) or type(exc).__name__
                log.warning("areasearch serve: plug-in planner %s cannot be used: %s", name, broken[name])
                continue
            if isinstance(planner, LearnedPlanner) or (weights and name == default):
                learned[name] = planner
        sha = getattr(learned.get(default), "weights_sha256", None) if weights else None
        policy = {"weights": weights, **({"weights_sha256": sha} if isinstance(sha, str) else {})} if weights else {}
    except AreaSearchError as exc:
        send({"fatal": " ".join(str(exc).split())})
        return
    except Exception:
        traceback.print_exc()
        send({"fatal": "the worker could not start (traceback in the log above)"})
        return
    ready = {"ready": True, "learned": sorted(n for n in learned if isinstance(learned[n], LearnedPlanner))}
    send({**ready, **policy, "broken": broken, "warm_s": round(time.perf_counter() - started, 3)})

    maps: OrderedDict[str, Any] = OrderedDict()
    while True:
        try:
            n, m = struct.unpack("<IQ", read_exactly(12))
            header = json.loads(read_exactly(n))
            payload = read_exactly(m)
        except EOFError:
            return
        send({"taken": True})  # this worker was alive to read it: from here, its death is the request's
        meta = header["map"]
        grid = maps.get(meta["key"])
        if grid is None and not payload:
            send({"need_map": True})
            continue
        began = time.perf_counter()
        try:
            if grid is None:
                cells = np.frombuffer(payload, dtype=np.int8).reshape(meta["height"], meta["width"])
                grid = GridCells(cells, meta["resolution"], tuple(meta["origin"]), meta["source"]).to_map()
                maps[meta["key"]] = grid
                while len(maps) > WORKER_MAPS:
                    maps.popitem(last=False)
            maps.move_to_end(meta["key"])
            req = header["request"]
            robots = robots_from_json(req["robots"], "request")
            target_ids, targets = targets_from_json(req["targets"], "request")
            method = req["method"]
            if method in broken:
                raise ConfigError(broken[method])
            assignments = assign_goals(
                grid,
                robots.poses,
                learned.get(method, method),  # a learned planner: its network, loaded once
                targets if len(target_ids) else None,
                robots.past_positions,
                robots.past_goals,
                radius_m=req["radius_m"],
                sensor_range_m=req["sensor_range_m"],
                seed=req["seed"],
                robot_names=robots.ids,
            )
            own = policy if method == default else None  # the answer names weights of your own
            text = dumps(assignments_json(assignments, robots.ids, target_ids, method, own))
        except AreaSearchError as exc:
            send({"status": 422, "detail": " ".join(str(exc).split())})
        except Exception:
            traceback.print_exc()  # the traceback stays in the server's log
            send({"status": 500, "detail": "internal error while planning (logged on the server)"})
        else:
            send({"status": 200, "plan_ms": round(1e3 * (time.perf_counter() - began), 3)}, text.encode())


class WorkerGone(Exception):
    """The worker process had ended before it was given the request (it died while idle)."""


class Worker:
    """One worker process, as the HTTP process sees it."""

    def __init__(self, proc: asyncio.subprocess.Process) -> None:
        self.proc = proc
        self.busy = False
        """Given a request and not yet back in the idle queue."""
        self.learned: list[str] = []
        self.plan_ms = 0.0
        """The worker's own time for its last answer (reading the request to writing the answer), ms."""

    async def send(self, header: dict[str, Any], payload: bytes = b"") -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(_frame(header, payload))
        await self.proc.stdin.drain()

    async def receive(self) -> tuple[dict[str, Any], bytes]:
        assert self.proc.stdout is not None
        n, m = struct.unpack("<IQ", await self.proc.stdout.readexactly(12))
        header = json.loads(await self.proc.stdout.readexactly(n))
        payload = await self.proc.stdout.readexactly(m) if m else b""
        return header, payload

    async def plan(self, request: dict[str, Any], grid: GridCells, key: str) -> tuple[int, str]:
        header = {"map": _map_header(grid, key), "request": request}
        try:
            await self.send(header)
            await self.receive()  # "taken"
        except (ConnectionError, asyncio.IncompleteReadError):  # the process had ended (or ended unasked)
            raise WorkerGone from None
        answer, payload = await self.receive()
        if answer.get("need_map"):
            await self.send(header, grid.cells.tobytes())
            await self.receive()  # "taken"
            answer, payload = await self.receive()
        if answer["status"] == 200:
            self.plan_ms = float(answer.get("plan_ms", 0.0))
            return 200, payload.decode()
        return int(answer["status"]), str(answer["detail"])

    async def stop(self) -> None:
        if self.proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                self.proc.kill()
        await self.proc.wait()


class WorkerPool:
    """``size`` worker processes; a request takes an idle one, a worker over its time or whose client
    left is killed and replaced by a fresh one (warmed before it takes requests)."""

    def __init__(self, config: ServeConfig, on_fatal: Callable[[str], None]) -> None:
        self.config = config
        self.on_fatal = on_fatal
        self.idle: asyncio.Queue[Worker] = asyncio.Queue()
        self.all: set[Worker] = set()
        self.warmed = 0
        self.started = time.perf_counter()
        self.learned: list[str] | None = None
        self.broken: dict[str, str] | None = None
        """Plug-in planners the workers found unusable, name -> why (None until a worker is warm)."""
        self.weights_sha256: str | None = None
        """SHA-256 of the --weights the workers loaded."""
        self.closing = False
        self.tasks: set[asyncio.Task[None]] = set()

    @property
    def ready(self) -> bool:
        return self.warmed >= self.config.workers

    def start(self) -> None:
        for _ in range(self.config.workers):
            self._spawn()

    def _spawn(self) -> None:
        task = asyncio.get_running_loop().create_task(self._start_one())
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)

    async def _start_one(self) -> None:
        env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        settings = {"method": self.config.method, "weights": self.config.weights}
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-c",
            "import json, sys; from areasearch.service.serve import worker_main; worker_main(json.loads(sys.argv[1]))",
            json.dumps(settings),
            stdin=asyncio.subprocess.PIPE,
            stdout=asyncio.subprocess.PIPE,
            env=env,
        )
        worker = Worker(proc)
        self.all.add(worker)
        try:
            header, _ = await worker.receive()
        except (asyncio.IncompleteReadError, ConnectionError):
            header = {"fatal": f"a worker process ended while starting (exit status {await proc.wait()})"}
        if "fatal" in header or self.closing:
            self.all.discard(worker)
            await worker.stop()
            if "fatal" in header and not self.closing:
                self.on_fatal(str(header["fatal"]))
            return
        worker.learned = list(header.get("learned", []))
        self.learned = worker.learned
        self.broken = dict(header.get("broken", {}))
        self.weights_sha256 = header.get("weights_sha256")
        if not self.ready:
            self.warmed += 1
            if self.ready:
                log.info(
                    "areasearch serve: ready: %d worker(s) warmed in %.1f s",
                    self.config.workers,
                    time.perf_counter() - self.started,
                )
        self.idle.put_nowait(worker)
        watch = asyncio.get_running_loop().create_task(self._watch(worker))
        self.tasks.add(watch)
        watch.add_done_callback(self.tasks.discard)

    async def _watch(self, worker: Worker) -> None:
        """Replace ``worker`` as soon as its process ends while it waits for a request (killed, out of
        memory), so that no request is handed to a dead worker; a busy worker's end is its request's."""
        status = await worker.proc.wait()
        if not worker.busy and not self.closing:
            await self._replace(worker, f"it ended while idle, exit status {status}")

    async def _replace(self, worker: Worker, why: str) -> None:
        if worker not in self.all:
            return  # replaced already
        log.warning("areasearch serve: worker %d stopped (%s); starting a fresh one", worker.proc.pid, why)
        self.all.discard(worker)
        waiting = [self.idle.get_nowait() for _ in range(self.idle.qsize())]
        for other in waiting:
            if other is not worker:
                self.idle.put_nowait(other)
        await worker.stop()
        if not self.closing:
            self._spawn()

    async def plan(
        self,
        request: dict[str, Any],
        grid: GridCells,
        key: str,
        deadline: float,
        disconnected: Callable[[], Awaitable[bool]],
    ) -> tuple[int, str, float]:
        """(status, body, the worker's own ms) of one assignment: 200 and the JSON, 422 and the library's
        message, 503 when no worker came free before ``deadline``, 504 past it, 499 when the client left."""
        loop = asyncio.get_running_loop()
        while True:
            try:
                worker = await asyncio.wait_for(self.idle.get(), max(deadline - loop.time(), 0.0))
            except TimeoutError:
                return (
                    503,
                    f"no worker came free within the time limit of {self.config.time_limit_s:g} s "
                    f"({self.config.workers} worker(s), all busy); try again",
                    0.0,
                )
            if worker.proc.returncode is None:
                break
            await self._replace(worker, f"it ended while idle, exit status {worker.proc.returncode}")
        worker.busy = True
        task = loop.create_task(worker.plan(request, grid, key))
        why = ""
        try:
            while not task.done():
                left = deadline - loop.time()
                if left <= 0:
                    why = "time limit"
                    break
                await asyncio.wait({task}, timeout=min(left, 0.05))
                if not task.done() and await disconnected():
                    why = "client disconnected"
                    break
            else:
                status, text = task.result()  # a worker that died mid-request raises here
                worker.busy = False
                self.idle.put_nowait(worker)
                return status, text, worker.plan_ms
        except WorkerGone:  # it died while idle, unseen so far: the request goes to another worker
            await self._replace(worker, "it ended while idle")
            return await self.plan(request, grid, key, deadline, disconnected)
        except (asyncio.IncompleteReadError, ConnectionError, json.JSONDecodeError, KeyError, struct.error):
            why = "the worker process ended or broke its protocol"
            log.error("areasearch serve: %s (exit status %s)", why, worker.proc.returncode)
        except BaseException:  # cancelled (server shutting down) or a bug: never leave the work running
            task.cancel()
            await self._replace(worker, "request cancelled")
            raise
        task.cancel()
        await self._replace(worker, why)
        if why == "time limit":
            limit = self.config.time_limit_s
            return 504, f"the assignment took longer than the time limit of {limit:g} s; stopped", 0.0
        if why == "client disconnected":
            return 499, "client disconnected; the assignment was stopped", 0.0
        return 500, "internal error: a worker process ended while planning (logged on the server)", 0.0

    async def close(self) -> None:
        self.closing = True
        for task in list(self.tasks):
            task.cancel()
        for worker in list(self.all):
            await worker.stop()
        self.all.clear()


# ---------------------------------------------------------------------------------- the HTTP side


def host_allowed(host: str, bound: str) -> bool:
    """Whether a request's ``Host`` header (``name[:port]``) names this service as only a client on this
    machine, or one that knows its address, would: an IP address, ``localhost`` (or a name under
    ``.localhost``), or the ``--host`` name. Any other name is how a DNS-rebinding page reaches a
    service on 127.0.0.1 (its own name, re-pointed at 127.0.0.1); an address cannot be re-pointed."""
    name = host.strip().lower()
    if name.startswith("["):  # [IPv6]:port
        name = name[1:].partition("]")[0]
    elif name.count(":") == 1:
        name = name.partition(":")[0]
    if name in ("localhost", bound.lower()) or name.endswith(".localhost"):
        return True
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


class Guard:
    """ASGI middleware in front of every route. Without a token: the ``Host`` header (421 unless
    :func:`host_allowed`) and, for a request with a body, ``Content-Type: application/json`` (415);
    with one: the bearer token (401, all but ``/health``). Then the body size (413 from
    ``Content-Length`` before reading, or as soon as a chunked body passes the limit) and the time to
    receive it (408, closing the connection); the body is handed on already read. After an answer
    given before its body was read, the rest of the body is read and dropped (so that a client
    sending it can read the answer), within the body's deadline (:class:`Connection`)."""

    def __init__(self, app: Any, config: ServeConfig) -> None:
        self.app = app
        self.config = config
        self.token = config.token.encode() if config.token else None

    @staticmethod
    async def _answer(send: Any, status: int, detail: str, headers: dict[str, str] | None = None) -> None:
        body = json.dumps({"detail": detail}).encode()
        raw = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
        raw += [(k.encode(), v.encode()) for k, v in (headers or {}).items()]
        await send({"type": "http.response.start", "status": status, "headers": raw})
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope.get("headers") or [])
        if self.token is None:
            # no token: a web page the user visits must not be able to use the service (CORS lets a
            # page send text/plain or form bodies to any address without asking; DNS rebinding makes
            # a page's own name point at 127.0.0.1)
            host = headers.get(b"host")
            if host is not None and not host_allowed(host.decode("latin-1"), self.config.host):
                await self._answer(
                    send,
                    421,
                    f"Host {short(host.decode('latin-1'), 64)} is not this service: without a token only an IP "
                    f"address, localhost or --host ({self.config.host}) is answered; set a token to use another name",
                )
                return
            kind = headers.get(b"content-type", b"").partition(b";")[0].strip().lower()
            if scope["method"] in ("POST", "PUT", "PATCH") and kind != b"application/json":
                got = short(kind.decode("latin-1"), 64) if kind else "none"
                await self._answer(
                    send,
                    415,
                    f"send Content-Type: application/json (got {got}); without a token other bodies are refused",
                )
                return
        elif scope["path"] != "/health":
            given = headers.get(b"authorization", b"")
            scheme, _, value = given.partition(b" ")
            if scheme.lower() != b"bearer" or not hmac.compare_digest(value.strip(), self.token):
                await self._answer(
                    send,
                    401,
                    "missing or wrong token: send 'Authorization: Bearer <token>'",
                    {"www-authenticate": "Bearer"},
                )
                return
        if scope["method"] not in ("POST", "PUT", "PATCH"):
            await self.app(scope, receive, send)
            return
        limit = self.config.max_body_bytes
        too_big = f"request body over the limit of {limit:,} bytes (--max-body-bytes)"
        declared = headers.get(b"content-length")
        if declared is not None and (not declared.isdigit() or len(declared) > 18 or int(declared) > limit):
            await self._answer(
                send, 413 if declared.isdigit() else 400, too_big if declared.isdigit() else "bad Content-Length"
            )
            return
        chunks: list[bytes] = []
        size = 0
        try:
            async with asyncio.timeout(self.config.time_limit_s):
                while True:
                    message = await receive()
                    if message["type"] == "http.disconnect":
                        return
                    chunk = message.get("body", b"")
                    size += len(chunk)
                    if size > limit:
                        await self._answer(send, 413, too_big)
                        return
                    chunks.append(chunk)
                    if not message.get("more_body", False):
                        break
        except TimeoutError:
            await self._answer(
                send, 408, f"request body not received within {self.config.time_limit_s:g} s", {"connection": "close"}
            )
            return
        body = b"".join(chunks)
        replayed = False

        async def replay() -> Any:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        await self.app(scope, replay, send)


@dataclass
class StoredMap:
    grid: GridCells
    key: str
    stored_at: float


def _key(grid: GridCells) -> str:
    digest = hashlib.blake2b(grid.cells.tobytes(), digest_size=16)
    digest.update(json.dumps([grid.cells.shape, grid.resolution, grid.origin_xy, grid.source]).encode())
    return digest.hexdigest()


def _map_summary(name: str, stored: StoredMap) -> dict[str, Any]:
    cells = stored.grid.cells
    h, w = cells.shape
    return {
        "name": name,
        "width": w,
        "height": h,
        "resolution": stored.grid.resolution,
        "origin": list(stored.grid.origin_xy),
        "unknown_cells": int((cells < 0).sum()),
        "key": stored.key,
    }


def _request_schema() -> dict[str, Any]:
    return {
        "required": True,
        "content": {"application/json": {"schema": {"$ref": "#/components/schemas/AssignRequest"}}},
    }


def create_app(config: ServeConfig, on_fatal: Callable[[str], None] | None = None) -> Any:
    """The ASGI application of the service (FastAPI inside :class:`Guard`); its worker pool starts with
    the application's lifespan. ``on_fatal(message)`` is called when a worker cannot start (bad
    ``--weights``); by default the message is logged."""
    config = config.validate()
    maps: dict[str, StoredMap] = {}
    fatal = on_fatal or (lambda message: log.error("areasearch serve: %s", message))
    pool = WorkerPool(config, fatal)

    @contextlib.asynccontextmanager
    async def lifespan(_: Any) -> AsyncIterator[None]:
        pool.start()
        try:
            yield
        finally:
            await pool.close()

    app = FastAPI(
        title="areasearch goal service",
        version=_version(),
        description="One long-term goal and path per robot on your own occupancy map (areasearch assign over HTTP).",
        lifespan=lifespan,
    )

    @app.exception_handler(Problem)
    async def problem(_: Request, exc: Problem) -> JSONResponse:
        return JSONResponse({"detail": exc.detail}, status_code=exc.status, headers=exc.headers)

    @app.exception_handler(Exception)
    async def internal(request: Request, exc: Exception) -> JSONResponse:
        log.error("areasearch serve: internal error on %s %s", request.method, request.url.path, exc_info=exc)
        return JSONResponse({"detail": "internal error (logged on the server)"}, status_code=500)

    def deadline() -> float:
        return asyncio.get_running_loop().time() + config.time_limit_s

    @app.get("/health", summary="ready (200) once every worker is warm, starting (503) before")
    async def health() -> JSONResponse:
        body = {
            "status": "ready" if pool.ready else "starting",
            "workers": config.workers,
            "idle_workers": pool.idle.qsize(),
            "default_method": config.method,
        }
        return JSONResponse(body, status_code=200 if pool.ready else 503)

    listing: list[dict[str, Any]] = []
    """The planners' origins (:func:`areasearch.planners.describe_planners`), read on the first GET."""

    @app.get("/methods", summary="the registered planners: built-in, shipped policies, plug-ins")
    async def methods() -> dict[str, Any]:
        if not listing:
            rows = describe_planners(check_plugins=False)  # a shadowed plug-in is not a registered planner
            listing.extend(row for row in rows if row["name"] in PLANNERS and row["status"] != "ignored")
            if config.method not in PLANNERS:  # weights of your own for a learned method not shipped
                listing.append({"name": config.method, "kind": "learned", "description": "a learned policy"})
        rows = []
        for row in listing:
            entry = {k: v for k, v in row.items() if k not in ("status", "error")}
            if entry["kind"] == "plug-in" and pool.broken is not None:
                problem = pool.broken.get(entry["name"])
                entry["status"] = "ok" if problem is None else "broken"
                if problem is not None:
                    entry["error"] = problem
            if config.weights and entry["name"] == config.method:
                entry.update(origin="your own weights (--weights)", weights=config.weights)
                entry.pop("weights_sha256", None)
                entry.update({"weights_sha256": pool.weights_sha256} if pool.weights_sha256 else {})
                entry["description"] = f"{entry['description']} (weights {config.weights})"
            rows.append(entry)
        return {"default": config.method, "methods": rows}

    @app.post("/assign", summary="one goal and path per robot", openapi_extra={"requestBody": _request_schema()})
    async def assign(request: Request) -> Response:
        began = time.perf_counter()
        ends = deadline()
        req = _parse_json(AssignRequest, await request.body())
        try:
            method = check_method(config.method if req.method is None else req.method)
        except ConfigError as exc:
            raise Problem(422, f"method: {exc}") from None
        if isinstance(req.map, str):
            stored = maps.get(req.map)
            if stored is None:
                known = ", ".join(sorted(maps)[:10]) or "none"
                raise Problem(
                    422, f"map: no stored map named {short(req.map, 64)} (stored: {known}); PUT /maps/{{name}} it"
                )
            grid, key = stored.grid, stored.key
        elif isinstance(req.map, dict):
            grid = _read_grid(req.map, "map", config.max_map_cells)
            key = _key(grid)
        else:
            raise Problem(422, "map: expected an OccupancyGrid object or the name of a stored map")
        job = {
            "robots": req.robots,
            "targets": req.targets,
            "method": method,
            "seed": req.seed,
            "radius_m": req.radius_m,
            "sensor_range_m": req.sensor_range_m,
        }
        if not pool.ready:
            raise Problem(503, "the service is starting (warming its workers); GET /health says when it is ready",
                          {"retry-after": "5"})  # fmt: skip
        status, text, plan_ms = await pool.plan(job, grid, key, ends, request.is_disconnected)
        if status != 200:
            raise Problem(status, text)
        took = f"plan;dur={plan_ms:.1f}, service;dur={1e3 * (time.perf_counter() - began):.1f}"
        return Response(text, media_type="application/json", headers={"server-timing": took})

    @app.put(
        "/maps/{name}",
        summary="store a map (an OccupancyGrid) under a name",
        openapi_extra={
            "requestBody": {
                "required": True,
                "content": {"application/json": {"schema": {"$ref": "#/components/schemas/OccupancyGrid"}}},
            }
        },
    )
    async def put_map(name: str, request: Request) -> JSONResponse:
        if not NAME.fullmatch(name):
            raise Problem(422, f"name: {short(name, 64)} is not a map name (letters, digits, _ . -; at most 64)")
        value = _parse_json(OccupancyGrid, await request.body(), f"maps/{name}")
        if name not in maps and len(maps) >= config.max_maps:
            raise Problem(507, f"{len(maps)} maps stored, the limit (--max-maps); DELETE /maps/{{name}} one first")
        grid = _read_grid(value, f"maps/{name}", config.max_map_cells)
        created = name not in maps
        maps[name] = StoredMap(grid, _key(grid), time.time())
        return JSONResponse(_map_summary(name, maps[name]), status_code=201 if created else 200)

    @app.get("/maps", summary="the stored maps")
    async def list_maps() -> dict[str, Any]:
        return {"maps": [_map_summary(name, stored) for name, stored in sorted(maps.items())]}

    @app.delete("/maps/{name}", summary="forget a stored map", status_code=204, response_model=None)
    async def delete_map(name: str) -> Response:
        if maps.pop(name, None) is None:
            raise Problem(404, f"no stored map named {short(name, 64)}")
        return Response(status_code=204)

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
            components = schema.setdefault("components", {}).setdefault("schemas", {})
            for model in (AssignRequest, OccupancyGrid):
                spec = model.model_json_schema(ref_template="#/components/schemas/{model}")
                components.update(spec.pop("$defs", {}))
                components[model.__name__] = spec
            # the map: an OccupancyGrid (a reference pydantic cannot follow from inside the model) or a name
            components["AssignRequest"]["properties"]["map"]["anyOf"][0] = {
                "$ref": "#/components/schemas/OccupancyGrid"
            }
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
    app.state.pool = pool
    app.state.maps = maps
    return Guard(app, config)


def _version() -> str:
    from .._version import __version__

    return __version__


# ---------------------------------------------------------------------------------- connections


class Connection(H11Protocol):
    """uvicorn's HTTP/1.1 connection with a deadline in every phase and a bound on open connections.

    Hand-written because uvicorn has neither: its ``timeout_keep_alive`` closes a connection idle
    *after an answer* only (one that never sends a byte, or sends its head a byte at a time, stays
    open for ever: each byte cancels the timer), and its ``limit_concurrency`` answers 503 only once a
    request's head has arrived, so connections beyond it stay open (a file descriptor each) for as
    long as they send nothing. Here each phase has its deadline, whatever the token: no request under
    way (just opened, or answered) ``idle_timeout_s`` without a byte; a head (request line and
    headers) ``header_timeout_s`` from its first byte; a body ``time_limit_s`` (plus a second, for
    :class:`Guard`'s 408 to go first); past it the connection is closed. While a received request is
    answered, the service's time limit rules. A connection over ``max_connections`` is answered 503
    and closed as soon as it is accepted."""

    settings: ServeConfig = ServeConfig()
    """The service's settings (:func:`connection_class` sets them)."""

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        self.deadline: asyncio.TimerHandle | None = None
        self.phase = ""
        super().connection_made(transport)
        if len(self.connections) > self.settings.max_connections:
            body = json.dumps(
                {"detail": f"more than {self.settings.max_connections} open connections (--max-connections); try again"}
            ).encode()
            head = "HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\nretry-after: 1\r\n"
            transport.write(f"{head}content-length: {len(body)}\r\nconnection: close\r\n\r\n".encode() + body)
            transport.close()
            return
        self._arm("idle", self.settings.idle_timeout_s)

    def data_received(self, data: bytes) -> None:
        if self.phase == "idle":  # the first byte of a request's head
            self._arm("head", self.settings.header_timeout_s)
        super().data_received(data)
        self._follow()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._follow()

    def connection_lost(self, exc: Exception | None) -> None:
        if self.deadline is not None:
            self.deadline.cancel()
        super().connection_lost(exc)

    def _follow(self) -> None:
        """The deadline of the phase h11 is in now (kept while the phase lasts)."""
        their = self.conn.their_state
        if their is h11.IDLE:
            if self.phase not in ("idle", "head"):
                buffered = bool(self.conn.trailing_data[0])  # part of a pipelined head, already here
                phase = "head" if buffered else "idle"
                self._arm(phase, self.settings.header_timeout_s if buffered else self.settings.idle_timeout_s)
        elif their is h11.SEND_BODY:
            if self.phase != "body":
                self._arm("body", self.settings.time_limit_s + 1.0)
        elif self.deadline is not None:  # the request is in (or the connection is closing)
            self.deadline.cancel()
            self.deadline = None
            self.phase = "answer"

    def _arm(self, phase: str, seconds: float) -> None:
        if self.deadline is not None:
            self.deadline.cancel()
        self.phase = phase
        self.deadline = self.loop.call_later(seconds, self._expired)

    def _expired(self) -> None:
        if not self.transport.is_closing():
            what = {"idle": "no request", "head": "no complete request head", "body": "no complete body"}
            limit = {"idle": self.settings.idle_timeout_s, "head": self.settings.header_timeout_s}
            seconds = limit.get(self.phase, self.settings.time_limit_s)
            log.info(
                "areasearch serve: closed a connection from %s: %s within %g s",
                f"{self.client[0]}:{self.client[1]}" if self.client else "?",
                what.get(self.phase, self.phase),
                seconds,
            )
            self.transport.close()


def connection_class(config: ServeConfig) -> type[H11Protocol]:
    """:class:`Connection` with ``config``'s deadlines and bound (uvicorn's ``http`` protocol class)."""
    return type("Connection", (Connection,), {"settings": config})


# ---------------------------------------------------------------------------------- running it


def _listen(host: str, port: int) -> socket.socket:
    """A listening socket on ``host``:``port`` (port 0: a free one), or ConfigError saying why not."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        sock = socket.socket(family, kind, proto)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(128)
    except OSError as exc:
        raise ConfigError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    sock.set_inheritable(False)
    return sock


def _enough_descriptors(config: ServeConfig) -> None:
    """Raise the process's soft limit on open files to what ``max_connections`` connections and the
    workers' pipes need (up to the hard limit), or ConfigError: past the limit the service could
    neither accept a connection nor start a worker."""
    import resource

    need = config.max_connections + 8 * config.workers + 64
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft < need:
        if hard != resource.RLIM_INFINITY and hard < need:
            raise ConfigError(
                f"max_connections {config.max_connections} needs {need} open files; this process may open "
                f"{hard} (ulimit -n): lower --max-connections"
            )
        resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))


def serve(config: ServeConfig) -> int:
    """Run the service until SIGINT / SIGTERM; ConfigError when it cannot listen or a worker cannot
    start (e.g. bad ``--weights``)."""
    import uvicorn

    config = config.validate()
    if config.host not in ("127.0.0.1", "localhost", "::1") and config.token is None:
        print(
            f"areasearch serve: warning: listening on {config.host} without a token; anyone who can reach "
            f"this port can use the service (set {TOKEN_VARIABLE} or --token)",
            file=sys.stderr,
        )
    _enough_descriptors(config)
    sock = _listen(config.host, config.port)
    failures: list[str] = []
    server: uvicorn.Server | None = None

    def on_fatal(message: str) -> None:
        failures.append(message)
        if server is not None:
            server.should_exit = True

    app = create_app(config, on_fatal)
    uv = uvicorn.Config(
        app,
        http=connection_class(config),
        log_level="info",
        server_header=False,
        proxy_headers=False,
        timeout_keep_alive=math.ceil(config.idle_timeout_s),  # Connection closes it on time
        lifespan="on",
    )
    server = uvicorn.Server(uv)
    host, port = sock.getsockname()[:2]
    url_host = f"[{host}]" if ":" in host else host
    print(
        f"areasearch serve: listening on http://{url_host}:{port} (method {config.method}, {config.workers} "
        f"worker(s), time limit {config.time_limit_s:g} s{', token required' if config.token else ''}); "
        "warming up, GET /health says when ready",
        file=sys.stderr,
        flush=True,
    )
    server.run(sockets=[sock])
    if failures:
        raise ConfigError(failures[0])
    return 0


def config_from_args(**values: Any) -> ServeConfig:
    """A :class:`ServeConfig` from the command line's values (None: the default), the token from
    :data:`TOKEN_VARIABLE` when not given. ``weights`` are loaded here, before the service listens
    (missing or damaged files, or weights for a planner that takes none, are one error at start-up);
    without ``method`` they name it (:func:`areasearch.planners.choose_planner`)."""
    given = {k: v for k, v in values.items() if v is not None}
    if "token" not in given and os.environ.get(TOKEN_VARIABLE):
        given["token"] = os.environ[TOKEN_VARIABLE]
    if "weights" in given:
        from ..planners import choose_planner

        given["method"] = choose_planner(given.get("method"), given["weights"]).method
    names = {f.name for f in dataclasses.fields(ServeConfig)}
    return ServeConfig(**{k: v for k, v in given.items() if k in names}).validate()
