"""The goal service's worker processes: :func:`worker_main` (one process: load and warm the planners,
then plan one request at a time) and the HTTP process's side, :class:`WorkerPool` (a request takes an
idle worker; a worker over its time, or whose client left, is killed and replaced by a warm one).

Workers talk to the HTTP process over their stdin / stdout in frames (:func:`frame`): ``"<IQ"`` (header
length, payload length), a JSON header (UTF-8), the payload (raw bytes: the map's int8 cells, the
answer's text), never pickle. A worker first answers "taken" to each request, so that a request sent
to a worker that had died while idle goes to another worker; it keeps the last :data:`WORKER_MAPS`
maps it planned on, by a hash of their cells, so that a map is sent to a worker once.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import struct
import sys
import time
import traceback
from collections import OrderedDict
from collections.abc import Awaitable, Callable
from typing import Any, BinaryIO

import numpy as np

from ..errors import AreaSearchError, ConfigError
from ..planners import PLANNERS, make_planner
from .occupancy_msg import GridCells
from .settings import ServeConfig

log = logging.getLogger("uvicorn.error")

WORKER_MAPS = 4
"""Maps a worker keeps read (least recently used dropped first)."""


def frame(header: dict[str, Any], payload: bytes = b"") -> bytes:
    head = json.dumps(header).encode()
    return struct.pack("<IQ", len(head), len(payload)) + head + payload


def map_header(grid: GridCells, key: str) -> dict[str, Any]:
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

    def send(header: dict[str, Any], payload: bytes = b"") -> None:
        out.write(frame(header, payload))
        out.flush()

    try:
        started = time.perf_counter()
        planners = _WorkerPlanners(settings["method"], settings.get("weights"), dict(settings.get("settings") or ()))
    except AreaSearchError as exc:
        send({"fatal": " ".join(str(exc).split())})
        return
    except Exception:
        traceback.print_exc()
        send({"fatal": "the worker could not start (traceback in the log above)"})
        return
    send({**planners.ready(), "warm_s": round(time.perf_counter() - started, 3)})
    while True:
        try:
            n, m = struct.unpack("<IQ", _read_exactly(inp, 12))
            header = json.loads(_read_exactly(inp, n))
            payload = _read_exactly(inp, m)
        except EOFError:
            return
        send({"taken": True})  # this worker was alive to read it: from here, its death is the request's
        send(*planners.answer(header, payload))


def _read_exactly(inp: BinaryIO, n: int) -> bytes:
    data = inp.read(n) if n else b""
    if len(data) != n:
        raise EOFError
    return data


class _WorkerPlanners:
    """A worker's planners: built and run once on a small map at start-up (numba's kernels, the
    networks' first calls), the learned ones (and the default method with --weights) kept; classical
    and plug-in planners are built afresh for each request, so that no two requests share state."""

    def __init__(self, default: str, weights: str | None, settings: dict[str, Any]) -> None:
        import torch

        from ..config import search_config
        from ..planners.learned import LearnedPlanner
        from .assign import assign_goals

        torch.set_num_threads(1)
        self.default = default
        self.config = search_config(settings)
        """The decision settings of every request (``areasearch serve --set``)."""
        self.maps: OrderedDict[str, Any] = OrderedDict()
        """The maps read so far, by key (the last :data:`WORKER_MAPS`)."""
        self.learned: dict[str, Any] = {}
        """Planners built once and kept: the learned networks, and the default method with --weights."""
        self.broken: dict[str, str] = {}
        """Plug-ins that fail to build or to plan on the warm-up map: answered 422 with the message."""
        warm = _warm_map().to_map()
        poses = [(1.05, 1.55, 0.0), (1.05, 0.75, 1.0)]
        plugins = list(PLANNERS.discovery().plugins)
        own_only = [] if default in PLANNERS.builtins or default in plugins else [default]  # a policy not shipped
        for name in [*PLANNERS.builtins, *own_only, *plugins]:
            try:
                planner = make_planner(name, weights=weights if name == default else None)
                assign_goals(warm, poses, planner, targets=[(2.0, 1.5)], config=self.config)
            except Exception as exc:  # a plug-in may raise anything; the built-ins and the default must work
                if name not in plugins or name == default:
                    raise
                self.broken[name] = " ".join(str(exc).split()) or type(exc).__name__
                log.warning("areasearch serve: plug-in planner %s cannot be used: %s", name, self.broken[name])
                continue
            if isinstance(planner, LearnedPlanner) or (weights and name == default):
                self.learned[name] = planner
        sha = getattr(self.learned.get(default), "weights_sha256", None) if weights else None
        self.policy = (
            {"weights": weights, **({"weights_sha256": sha} if isinstance(sha, str) else {})} if weights else {}
        )
        self.networks = sorted(n for n in self.learned if isinstance(self.learned[n], LearnedPlanner))

    def ready(self) -> dict[str, Any]:
        """The worker's first frame: ready, its learned planners, the weights' record, the broken plug-ins."""
        return {"ready": True, "learned": self.networks, **self.policy, "broken": self.broken}

    def answer(self, header: dict[str, Any], payload: bytes) -> tuple[dict[str, Any], bytes]:
        """The answer frame to one request: 200 and the JSON of ``areasearch assign``, 422 and the
        library's message, 500 (traceback in the log), or a request for the map's cells when this
        worker has not read that map."""
        meta = header["map"]
        maps = self.maps
        grid = maps.get(meta["key"])
        if grid is None and not payload:
            return {"need_map": True}, b""
        began = time.perf_counter()
        try:
            if grid is None:
                cells = np.frombuffer(payload, dtype=np.int8).reshape(meta["height"], meta["width"])
                grid = GridCells(cells, meta["resolution"], tuple(meta["origin"]), meta["source"]).to_map()
                maps[meta["key"]] = grid
                while len(maps) > WORKER_MAPS:
                    maps.popitem(last=False)
            maps.move_to_end(meta["key"])
            text = self._plan(grid, header["request"])
        except AreaSearchError as exc:
            return {"status": 422, "detail": " ".join(str(exc).split())}, b""
        except Exception:
            traceback.print_exc()  # the traceback stays in the server's log
            return {"status": 500, "detail": "internal error while planning (logged on the server)"}, b""
        return {"status": 200, "plan_ms": round(1e3 * (time.perf_counter() - began), 3)}, text.encode()

    def _plan(self, grid: Any, req: dict[str, Any]) -> str:
        from .answer import assignments_json, dumps
        from .assign import assign_goals
        from .team import robots_from_json, targets_from_json

        robots = robots_from_json(req["robots"], "request")
        target_ids, targets = targets_from_json(req["targets"], "request")
        method = req["method"]
        if method in self.broken:
            raise ConfigError(self.broken[method])
        assignments = assign_goals(
            grid,
            robots.poses,
            self.learned.get(method, method),  # a learned planner: its network, loaded once
            targets if len(target_ids) else None,
            robots.past_positions,
            robots.past_goals,
            config=self.config,
            radius_m=req["radius_m"],
            sensor_range_m=req["sensor_range_m"],
            seed=req["seed"],
            robot_names=robots.ids,
        )
        own = self.policy if method == self.default else None  # the answer names weights of your own
        return dumps(assignments_json(assignments, robots.ids, target_ids, method, own))


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
        self.proc.stdin.write(frame(header, payload))
        await self.proc.stdin.drain()

    async def receive(self) -> tuple[dict[str, Any], bytes]:
        assert self.proc.stdout is not None
        n, m = struct.unpack("<IQ", await self.proc.stdout.readexactly(12))
        header = json.loads(await self.proc.stdout.readexactly(n))
        payload = await self.proc.stdout.readexactly(m) if m else b""
        return header, payload

    async def plan(self, request: dict[str, Any], grid: GridCells, key: str) -> tuple[int, str]:
        header = {"map": map_header(grid, key), "request": request}
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
        settings = {"method": self.config.method, "weights": self.config.weights, "settings": self.config.settings}
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-c",
            "import json, sys; from areasearch.service.pool import worker_main; worker_main(json.loads(sys.argv[1]))",
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
