"""What the goal service checks before a route runs, where FastAPI has no setting for it: the request
filter and body limits (:class:`RequestLimits`, ASGI middleware) and the connection deadlines
(:class:`Connection`, uvicorn's HTTP/1.1 protocol with a deadline in each phase and a bound on open
connections). The token is a route dependency (:func:`areasearch.service.app.require_token`).
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
import logging
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

from ..inputs import short
from .settings import ServeConfig

log = logging.getLogger("uvicorn.error")


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


class RequestLimits:
    """ASGI middleware in front of every route. Without a token, what a web page could send is refused:
    a ``Host`` header that names another service (421 unless :func:`host_allowed`) and a request body
    other than ``Content-Type: application/json`` (415). Then, for a request with a body, its size (413
    from ``Content-Length`` before reading, or as soon as a chunked body passes the limit) and the time
    to receive it (408, closing the connection); the body is handed on already read. After an answer
    given before its body was read, the rest of the body is read and dropped (so that a client sending
    it can read the answer), within the body's deadline (:class:`Connection`)."""

    def __init__(self, app: Any, config: ServeConfig) -> None:
        self.app = app
        self.config = config

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
        if self.config.token is None:
            refusal = self._web_page_refusal(scope["method"], headers)
            if refusal is not None:
                await self._answer(send, *refusal)
                return
        if scope["method"] not in ("POST", "PUT", "PATCH"):
            await self.app(scope, receive, send)
            return
        body = await self._body(headers, receive, send)
        if body is None:
            return
        replayed = False

        async def replay() -> Any:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        await self.app(scope, replay, send)

    def _web_page_refusal(self, method: str, headers: dict[bytes, bytes]) -> tuple[int, str] | None:
        """Without a token, a web page the user visits must not be able to use the service (CORS lets a
        page send text/plain or form bodies to any address without asking; DNS rebinding makes a page's
        own name point at 127.0.0.1): (421, why) for a foreign ``Host``, (415, why) for a body that is
        not JSON; None to go on."""
        host = headers.get(b"host")
        if host is not None and not host_allowed(host.decode("latin-1"), self.config.host):
            return (
                421,
                f"Host {short(host.decode('latin-1'), 64)} is not this service: without a token only an IP "
                f"address, localhost or --host ({self.config.host}) is answered; set a token to use another name",
            )
        kind = headers.get(b"content-type", b"").partition(b";")[0].strip().lower()
        if method in ("POST", "PUT", "PATCH") and kind != b"application/json":
            got = short(kind.decode("latin-1"), 64) if kind else "none"
            return 415, f"send Content-Type: application/json (got {got}); without a token other bodies are refused"
        return None

    async def _body(self, headers: dict[bytes, bytes], receive: Any, send: Any) -> bytes | None:
        """The whole request body, or None once refused (413, 400 for a bad ``Content-Length``, 408) or
        when the client left."""
        limit = self.config.max_body_bytes
        too_big = f"request body over the limit of {limit:,} bytes (--max-body-bytes)"
        declared = headers.get(b"content-length")
        if declared is not None and (not declared.isdigit() or len(declared) > 18 or int(declared) > limit):
            await self._answer(
                send, 413 if declared.isdigit() else 400, too_big if declared.isdigit() else "bad Content-Length"
            )
            return None
        chunks: list[bytes] = []
        size = 0
        try:
            async with asyncio.timeout(self.config.time_limit_s):
                while True:
                    message = await receive()
                    if message["type"] == "http.disconnect":
                        return None
                    chunk = message.get("body", b"")
                    size += len(chunk)
                    if size > limit:
                        await self._answer(send, 413, too_big)
                        return None
                    chunks.append(chunk)
                    if not message.get("more_body", False):
                        break
        except TimeoutError:
            await self._answer(
                send, 408, f"request body not received within {self.config.time_limit_s:g} s", {"connection": "close"}
            )
            return None
        return b"".join(chunks)


class Connection(H11Protocol):
    """uvicorn's HTTP/1.1 connection with a deadline in every phase and a bound on open connections.

    Hand-written because uvicorn has neither: its ``timeout_keep_alive`` closes a connection idle
    *after an answer* only (one that never sends a byte, or sends its head a byte at a time, stays
    open for ever: each byte cancels the timer), and its ``limit_concurrency`` answers 503 only once a
    request's head has arrived, so connections beyond it stay open (a file descriptor each) for as
    long as they send nothing. Here each phase has its deadline, whatever the token: no request under
    way (just opened, or answered) ``idle_timeout_s`` without a byte; a head (request line and
    headers) ``header_timeout_s`` from its first byte; a body ``time_limit_s`` (plus a second, for
    :class:`RequestLimits`' 408 to go first); past it the connection is closed. While a received request is
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
