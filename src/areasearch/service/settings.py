"""Settings of ``areasearch serve`` (:class:`ServeConfig`), checked before the service listens, and the
names every part of the service shares: the token's environment variable and a stored map's name.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

from ..errors import ConfigError
from ..inputs import LIMIT_VARIABLES, limits, short
from ..planners import LEARNED, PLANNERS, check_takes_weights, make_planner

TOKEN_VARIABLE = "AREASEARCH_SERVE_TOKEN"
"""Environment variable holding the bearer token (rather than ``--token``, which ``ps`` shows)."""

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
"""A stored map's name: letters, digits, ``_ . -``, at most 64 characters (a key, never a path); matched
whole (``NAME.fullmatch``: ``$`` alone would let a trailing newline through)."""


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
    settings: tuple[tuple[str, Any], ...] = ()
    """Decision settings applied to every request, by their full keys (as ``areasearch assign --set``
    takes them: ``candidates.*``, ``paths.*``, ``decisions.*``, world settings such as
    ``world.targets.count``), e.g. ``(("candidates.distance_cell_m", 0.1),)``; empty: the defaults."""
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
        from ..config import search_config

        search_config(dict(self.settings))  # ConfigError naming a bad setting, before the service listens
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
