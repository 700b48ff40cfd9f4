"""The goal service's HTTP side: its routes on two :class:`~fastapi.APIRouter` (``public``: ``/health``;
``router``: everything else, behind the bearer token) and :func:`create_app`, the ASGI application.

FastAPI's own idioms: typed request bodies (:class:`~areasearch.service.schema.AssignRequest`, an
:class:`~areasearch.service.occupancy_msg.OccupancyGrid` for ``PUT /maps/{name}``), from which the
OpenAPI schema is generated; the token as a dependency (:func:`require_token`, on
:class:`~fastapi.security.HTTPBearer`); the service's state as a dependency (:func:`get_service`);
the refusals as exceptions (:class:`~areasearch.service.schema.Problem`, an HTTPException) and a
:class:`~fastapi.exceptions.RequestValidationError` handler that words a body that does not fit in
one line (:func:`refuse_invalid`). Every route uses :class:`ServiceRoute`: a body is read by the
service's JSON reader (:func:`~areasearch.service.schema.read_json`) whatever its ``Content-Type``
(without a token, :class:`~areasearch.service.limits.RequestLimits` has refused any other before), and
a body that is not JSON is answered 400 after the route's dependencies, so that a refusal names the
first thing wrong in the order token, map name, body. ``/openapi.json`` and ``/docs`` are routes of
``router`` too, so that they want the token.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import json
import logging
import time
from collections.abc import AsyncIterator, Callable, Coroutine
from dataclasses import dataclass, field
from typing import Annotated, Any

from fastapi import APIRouter, Depends, FastAPI, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import HTMLResponse, JSONResponse, Response
from fastapi.routing import APIRoute
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.datastructures import Headers

from ..errors import ConfigError
from ..inputs import short
from ..planners import PLANNERS, describe_planners
from .limits import RequestLimits
from .occupancy_msg import GridCells, OccupancyGrid
from .pool import WorkerPool
from .schema import AssignRequest, Detail, Problem, read_grid, read_json, validation_problem
from .settings import NAME, ServeConfig, check_method

log = logging.getLogger("uvicorn.error")


# ---------------------------------------------------------------------------------- the service's state


@dataclass
class StoredMap:
    grid: GridCells
    key: str
    stored_at: float


def map_key(grid: GridCells) -> str:
    """A hash of a map's cells and frame: how the workers know a map they have read."""
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


@dataclass
class Service:
    """What the routes of one application share: its settings, its workers, its stored maps."""

    config: ServeConfig
    pool: WorkerPool
    maps: dict[str, StoredMap] = field(default_factory=dict)
    listing: list[dict[str, Any]] = field(default_factory=list)
    """The planners' origins (:func:`areasearch.planners.describe_planners`), read on the first GET."""


def get_service(request: Request) -> Service:
    """The :class:`Service` of the application answering ``request``."""
    service: Service = request.app.state.service
    return service


ServiceDep = Annotated[Service, Depends(get_service)]

bearer = HTTPBearer(auto_error=False, description="the service's token (--token or AREASEARCH_SERVE_TOKEN)")


async def require_token(
    service: ServiceDep, credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]
) -> None:
    """401 unless the request carries ``Authorization: Bearer <token>`` (when the service has a token)."""
    token = service.config.token
    if token is None:
        return
    given = credentials.credentials.encode("latin-1") if credentials is not None else b""
    if credentials is None or not hmac.compare_digest(given, token.encode()):
        raise Problem(
            401, "missing or wrong token: send 'Authorization: Bearer <token>'", {"www-authenticate": "Bearer"}
        )


def map_name(name: str) -> str:
    """The ``{name}`` of ``PUT /maps/{name}``: 422 unless a map name (letters, digits, ``_ . -``)."""
    if not NAME.fullmatch(name):
        raise Problem(422, f"name: {short(name, 64)} is not a map name (letters, digits, _ . -; at most 64)")
    return name


# ---------------------------------------------------------------------------------- reading a body


class Malformed:
    """The body of a request that is not JSON: its 400, answered by :func:`refuse_invalid`."""

    def __init__(self, problem: Problem) -> None:
        self.problem = problem


class JSONBodyRequest(Request):
    """A request whose body is read as JSON by :func:`~areasearch.service.schema.read_json`, whatever
    its ``Content-Type``; a body that is not JSON reads as :class:`Malformed`, which no body model
    accepts. ``began`` and ``arrived`` (the event loop's clock): when the request reached its route,
    before its body was parsed; its time limit and its ``Server-Timing`` count from there."""

    def __init__(self, scope: Any, receive: Any) -> None:
        super().__init__(scope, receive)
        self.began = time.perf_counter()
        self.arrived = asyncio.get_running_loop().time()

    @property
    def headers(self) -> Headers:
        if not hasattr(self, "_headers"):
            raw = [(k, v) for k, v in self.scope["headers"] if k != b"content-type"]
            self._headers = Headers(raw=[*raw, (b"content-type", b"application/json")])
        return self._headers

    async def json(self) -> Any:
        if not hasattr(self, "_body_json"):
            try:
                self._body_json = read_json(await self.body())
            except Problem as exc:
                self._body_json = Malformed(exc)
        return self._body_json


class ServiceRoute(APIRoute):
    """A route of the service: its requests are :class:`JSONBodyRequest`."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def route(request: Request) -> Response:
            return await handler(JSONBodyRequest(request.scope, request.receive))

        return route


def _refusal(request: Request, exc: RequestValidationError) -> Problem:
    """The one-line refusal of a body FastAPI found wrong: 400 when it is not JSON or empty, else 422
    naming the first field at fault, inside the body or, for ``PUT /maps/{name}``, ``maps/<name>``."""
    if isinstance(exc.body, Malformed):
        return exc.body.problem
    errors = exc.errors()
    if errors[0]["type"] == "missing" and tuple(errors[0]["loc"]) == ("body",):
        return Problem(400, "malformed JSON: the request body is empty")
    name = request.path_params.get("name")
    inside = [{**e, "loc": _in_body(tuple(e["loc"]))} for e in errors]
    return validation_problem(inside, "" if name is None else f"maps/{name}")


def _in_body(loc: tuple[Any, ...]) -> tuple[Any, ...]:
    """A location in FastAPI's terms (``("body", "robots", 0)``) as one inside the body."""
    return loc[1:] if loc[:1] == ("body",) else loc


async def refuse_invalid(request: Request, exc: Exception) -> Response:
    """The answer to a :class:`~fastapi.exceptions.RequestValidationError`: :func:`_refusal`'s."""
    assert isinstance(exc, RequestValidationError)
    return await http_exception_handler(request, _refusal(request, exc))


async def internal_error(request: Request, exc: Exception) -> JSONResponse:
    log.error("areasearch serve: internal error on %s %s", request.method, request.url.path, exc_info=exc)
    return JSONResponse({"detail": "internal error (logged on the server)"}, status_code=500)


# ---------------------------------------------------------------------------------- routes

_REFUSED = {"model": Detail, "description": "refused: one line saying why"}
public = APIRouter(route_class=ServiceRoute)
router = APIRouter(
    route_class=ServiceRoute, dependencies=[Depends(require_token)], responses={401: _REFUSED, 422: _REFUSED}
)


@public.get("/health", summary="ready (200) once every worker is warm, starting (503) before")
async def health(service: ServiceDep) -> JSONResponse:
    pool = service.pool
    body = {
        "status": "ready" if pool.ready else "starting",
        "workers": service.config.workers,
        "idle_workers": pool.idle.qsize(),
        "default_method": service.config.method,
        "settings": dict(service.config.settings),
    }
    return JSONResponse(body, status_code=200 if pool.ready else 503)


@router.get("/methods", summary="the registered planners: built-in, shipped policies, plug-ins")
async def methods(service: ServiceDep) -> dict[str, Any]:
    config, listing, broken = service.config, service.listing, service.pool.broken
    if not listing:
        rows = describe_planners(check_plugins=False)  # a shadowed plug-in is not a registered planner
        listing.extend(row for row in rows if row["name"] in PLANNERS and row["status"] != "ignored")
        if config.method not in PLANNERS:  # weights of your own for a learned method not shipped
            listing.append({"name": config.method, "kind": "learned", "description": "a learned policy"})
    rows = []
    for row in listing:
        entry = {k: v for k, v in row.items() if k not in ("status", "error")}
        if entry["kind"] == "plug-in" and broken is not None:
            problem = broken.get(entry["name"])
            entry["status"] = "ok" if problem is None else "broken"
            if problem is not None:
                entry["error"] = problem
        if config.weights and entry["name"] == config.method:
            entry.update(origin="your own weights (--weights)", weights=config.weights)
            entry.pop("weights_sha256", None)
            entry.update({"weights_sha256": service.pool.weights_sha256} if service.pool.weights_sha256 else {})
            entry["description"] = f"{entry['description']} (weights {config.weights})"
        rows.append(entry)
    return {"default": config.method, "methods": rows}


@router.post(
    "/assign",
    summary="one goal and path per robot",
    responses={code: _REFUSED for code in (400, 413, 499, 503, 504)},
)
async def assign(req: AssignRequest, request: JSONBodyRequest, service: ServiceDep) -> Response:
    config, pool = service.config, service.pool
    try:
        method = check_method(config.method if req.method is None else req.method)
    except ConfigError as exc:
        raise Problem(422, f"method: {exc}") from None
    if isinstance(req.map, str):
        stored = service.maps.get(req.map)
        if stored is None:
            known = ", ".join(sorted(service.maps)[:10]) or "none"
            raise Problem(
                422, f"map: no stored map named {short(req.map, 64)} (stored: {known}); PUT /maps/{{name}} it"
            )
        grid, key = stored.grid, stored.key
    elif isinstance(req.map, dict):
        grid = read_grid(req.map, "map", config.max_map_cells)
        key = map_key(grid)
    else:
        raise Problem(422, "map: expected an OccupancyGrid object or the name of a stored map")
    job = {"robots": req.robots, "targets": req.targets, "method": method, "seed": req.seed,
           "radius_m": req.radius_m, "sensor_range_m": req.sensor_range_m}  # fmt: skip
    if not pool.ready:
        raise Problem(503, "the service is starting (warming its workers); GET /health says when it is ready",
                      {"retry-after": "5"})  # fmt: skip
    ends = request.arrived + config.time_limit_s
    status, text, plan_ms = await pool.plan(job, grid, key, ends, request.is_disconnected)
    if status != 200:
        raise Problem(status, text)
    took = f"plan;dur={plan_ms:.1f}, service;dur={1e3 * (time.perf_counter() - request.began):.1f}"
    return Response(text, media_type="application/json", headers={"server-timing": took})


@router.put(
    "/maps/{name}",
    summary="store a map (an OccupancyGrid) under a name",
    responses={code: _REFUSED for code in (400, 413, 507)},
)
async def put_map(msg: OccupancyGrid, name: Annotated[str, Depends(map_name)], service: ServiceDep) -> JSONResponse:
    maps, config = service.maps, service.config
    if name not in maps and len(maps) >= config.max_maps:
        raise Problem(507, f"{len(maps)} maps stored, the limit (--max-maps); DELETE /maps/{{name}} one first")
    grid = read_grid(msg, f"maps/{name}", config.max_map_cells)
    created = name not in maps
    maps[name] = StoredMap(grid, map_key(grid), time.time())
    return JSONResponse(_map_summary(name, maps[name]), status_code=201 if created else 200)


@router.get("/maps", summary="the stored maps")
async def list_maps(service: ServiceDep) -> dict[str, Any]:
    return {"maps": [_map_summary(name, stored) for name, stored in sorted(service.maps.items())]}


@router.delete("/maps/{name}", summary="forget a stored map", status_code=204, response_model=None)
async def delete_map(name: str, service: ServiceDep) -> Response:
    if service.maps.pop(name, None) is None:
        raise Problem(404, f"no stored map named {short(name, 64)}")
    return Response(status_code=204)


@router.api_route("/openapi.json", methods=["GET", "HEAD"], include_in_schema=False)
async def openapi(request: Request) -> JSONResponse:
    return JSONResponse(request.app.openapi())


@router.api_route("/docs", methods=["GET", "HEAD"], include_in_schema=False)
async def docs(request: Request) -> HTMLResponse:
    root = request.scope.get("root_path", "").rstrip("/")
    return get_swagger_ui_html(
        openapi_url=f"{root}/openapi.json",
        title=f"{request.app.title} - Swagger UI",
        oauth2_redirect_url=f"{root}/docs/oauth2-redirect",
    )


@router.api_route("/docs/oauth2-redirect", methods=["GET", "HEAD"], include_in_schema=False)
async def docs_redirect() -> HTMLResponse:
    return get_swagger_ui_oauth2_redirect_html()


@router.api_route("/redoc", methods=["GET", "HEAD"], include_in_schema=False)
async def redoc(request: Request) -> HTMLResponse:
    root = request.scope.get("root_path", "").rstrip("/")
    return get_redoc_html(openapi_url=f"{root}/openapi.json", title=f"{request.app.title} - ReDoc")


# ---------------------------------------------------------------------------------- the application


def create_app(config: ServeConfig, on_fatal: Callable[[str], None] | None = None) -> Any:
    """The ASGI application of the service (FastAPI inside :class:`~areasearch.service.limits.RequestLimits`);
    its worker pool starts with the application's lifespan. ``on_fatal(message)`` is called when a
    worker cannot start (bad ``--weights``); by default the message is logged."""
    config = config.validate()
    fatal = on_fatal or (lambda message: log.error("areasearch serve: %s", message))
    service = Service(config, WorkerPool(config, fatal))

    @contextlib.asynccontextmanager
    async def lifespan(_: Any) -> AsyncIterator[None]:
        service.pool.start()
        try:
            yield
        finally:
            await service.pool.close()

    app = FastAPI(
        title="areasearch goal service",
        version=_version(),
        description="One long-term goal and path per robot on your own occupancy map (areasearch assign over HTTP).",
        lifespan=lifespan,
        openapi_url=None,  # /openapi.json and /docs are routes of `router`: behind the token
        docs_url=None,
        redoc_url=None,
    )
    app.include_router(public)
    app.include_router(router)
    app.add_exception_handler(RequestValidationError, refuse_invalid)
    app.add_exception_handler(Exception, internal_error)
    app.state.service = service
    return RequestLimits(app, config)


def _version() -> str:
    from .._version import __version__

    return __version__
