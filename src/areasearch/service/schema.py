"""The goal service's request bodies and refusals: the typed bodies (:class:`AssignRequest`, and
:class:`~areasearch.service.occupancy_msg.OccupancyGrid` for a stored map), from which FastAPI
generates the OpenAPI schema; the JSON reader of every body (:func:`read_json`); and the one-line
refusals (:class:`Problem`), with the words of a validation error (:func:`validation_problem`).

A body is read by :func:`read_json` (orjson, pydantic-core for what orjson reads otherwise) and then
validated in Python mode: ``model_validate_json`` would copy the map's ``data`` (3.3 M cells on the
largest bundled map) into Python objects first (``benchmarks/bench_serve_parse.py``); the map's
cells are then converted in one C pass (:func:`~areasearch.service.occupancy_msg.grid_cells`).
``robots`` and ``targets`` are checked by :func:`areasearch.service.team.robots_from_json` /
``targets_from_json``, with the messages of ``areasearch assign``: the schema types them for the
documentation (:class:`Robot`, :class:`Target`) but does not validate them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Annotated, Any

import orjson
from fastapi import HTTPException
from pydantic import BaseModel, ConfigDict, Field, SkipValidation, ValidationError
from pydantic.json_schema import SkipJsonSchema
from pydantic_core import from_json

from ..errors import AreaSearchError
from ..inputs import clip
from .occupancy_msg import GridCells, OccupancyGrid, grid_cells
from .settings import NAME

XY = Annotated[list[float], Field(min_length=2, max_length=2)]
"""An [x, y] pair of numbers, metres (schema only)."""


class Robot(BaseModel):
    """A robot of ``POST /assign``, as in ``areasearch assign``'s ``robots.json`` (schema only: the
    entries are checked by :func:`~areasearch.service.team.robots_from_json`)."""

    model_config = ConfigDict(extra="forbid")

    id: str | SkipJsonSchema[None] = Field(None, min_length=1, description="default: robot_<index>")
    x: float
    y: float
    yaw: float = 0.0
    past_positions: list[XY] = Field(default=[], description="newest first")
    past_goals: list[XY | None] = Field(default=[], description="newest first")


class Target(BaseModel):
    """A target of ``POST /assign``, as in ``targets.json`` (schema only, like :class:`Robot`)."""

    model_config = ConfigDict(extra="forbid")

    id: str | SkipJsonSchema[None] = Field(None, min_length=1, description="default: target_<index>")
    x: float
    y: float


MapName = Annotated[str, Field(pattern=NAME.pattern, description="a map stored by PUT /maps/{name}")]


class AssignRequest(BaseModel):
    """``POST /assign``. The map is an OccupancyGrid or a stored map's name, read by the route (413 for
    too many cells, the library's messages for its values); ``robots`` and ``targets`` are checked by
    :func:`~areasearch.service.team.robots_from_json` / ``targets_from_json``; the rest by the schema."""

    model_config = ConfigDict(strict=True, extra="forbid")

    map: SkipValidation[OccupancyGrid | MapName]
    robots: Annotated[list[SkipValidation[Robot]], Field(json_schema_extra={"minItems": 1})]
    targets: list[SkipValidation[Target]] = []
    method: str | None = None
    seed: int = 0
    radius_m: float | None = None
    sensor_range_m: float | None = None


class Detail(BaseModel):
    """The body of every refusal: one line."""

    detail: str


class Problem(HTTPException):
    """A request refused: HTTP ``status_code`` and a one-line ``detail`` (FastAPI's answer to an
    HTTPException: ``{"detail": ...}``)."""

    def __init__(self, status: int, detail: str, headers: Mapping[str, str] | None = None) -> None:
        super().__init__(status, " ".join(detail.split()), dict(headers) if headers else None)


JSON_WORDS = {
    "list_type": "Input should be a valid array",
    "dict_type": "Input should be an object",
    "model_type": "Input should be an object",
    "model_attributes_type": "Input should be an object",
}
"""Messages of the pydantic errors that Python-mode validation words in Python's terms ("a valid list",
"a valid dictionary or instance of Pose", "a valid dictionary or object to extract fields from"), in
the terms of the JSON a client sent."""


def _where(loc: Sequence[Any], prefix: str) -> str:
    text = prefix
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else str(part)
    return text or "body"


def validation_problem(errors: Sequence[Mapping[str, Any]], prefix: str = "") -> Problem:
    """422 naming the first field at fault in pydantic's ``errors`` (and how many more), its location
    after ``prefix`` (``map``, ``maps/<name>``; none: the body's own fields)."""
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


def read_json(body: bytes) -> Any:
    """The JSON value of a request body (:func:`_loads`); 400 when it is empty or not JSON."""
    if not body:
        raise Problem(400, "malformed JSON: the request body is empty")
    try:
        return _loads(body)
    except ValueError as exc:
        raise Problem(400, f"malformed JSON: Invalid JSON: {clip(str(exc))}") from None
    except RecursionError:
        raise Problem(400, "malformed JSON: nested too deeply") from None


def read_grid(value: Any, source: str, max_cells: int) -> GridCells:
    """An OccupancyGrid (validated, or the parsed JSON of one) as checked cells: 422 for a field or
    value at fault, 413 for more cells than ``max_cells``."""
    if isinstance(value, OccupancyGrid):
        msg = value
    else:
        try:
            msg = OccupancyGrid.model_validate(value)
        except ValidationError as exc:
            raise validation_problem(exc.errors(include_url=False, include_context=False), source) from None
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
