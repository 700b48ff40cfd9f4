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

The parts: the settings (:mod:`.settings`), the request bodies and refusals (:mod:`.schema`), the
routes and the application (:mod:`.app`), the worker processes (:mod:`.pool`), the request and
connection limits (:mod:`.limits`); this module runs them (:func:`serve`).

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
other than ``application/json`` 415 (what a web page could send:
:class:`~areasearch.service.limits.RequestLimits`). Every connection has a deadline in each phase and
their number a bound (:class:`~areasearch.service.limits.Connection`).
"""

from __future__ import annotations

import dataclasses
import math
import os
import socket
import sys
from typing import Any

from ..errors import ConfigError
from .app import create_app
from .limits import connection_class
from .settings import TOKEN_VARIABLE, ServeConfig

__all__ = ["ServeConfig", "config_from_args", "create_app", "serve"]


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
