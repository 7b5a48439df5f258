"""A read deadline on request bodies: a client that drips its body gets 408 and a closed connection.

Why: uvicorn bounds how long a connection may stay idle between requests, but not how long a
request's body may take to arrive. A client sending a batch body one byte every few seconds held a
connection (and the coroutine reading it) for 33-180 s, and 200 such clients hold 200 of them for
as long as they like. So every body read goes through `BodyDeadline`, a pure ASGI middleware
around ``receive``, the outermost of the app's own middlewares:

- no chunk may take longer than `timeout_s` to arrive after the previous one (or after the app asked
  for the first);
- the whole body may take `timeout_s` plus one second for every `min_rate_bytes` already received,
  so a large upload at a reasonable rate is never cut, while a drip gains nothing.

Past either, the app's read fails (`BodyTimeout`), whatever the app answers instead is dropped, and
the client gets 408 with ``Connection: close`` (uvicorn then closes the connection). Once the body
has arrived in full, ``receive`` is passed through untouched (it then only waits for a disconnect,
which a streaming answer may do for as long as it streams).
"""

from __future__ import annotations

import asyncio
import logging
import time

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from bayesian_fields_service.api.problems import problem_response

log = logging.getLogger(__name__)


class BodyTimeout(Exception):
    """The request body did not arrive in time (raised into the app's read)."""


class BodyDeadline:
    """Pure ASGI middleware: 408 and a closed connection for a body slower than its deadline."""

    def __init__(self, app: ASGIApp, timeout_s: float, min_rate_bytes: int) -> None:
        self.app = app
        self.timeout_s = timeout_s
        self.min_rate_bytes = min_rate_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        read = _Read(receive, self.timeout_s, self.min_rate_bytes)
        answered = False

        async def guarded_send(message: Message) -> None:
            nonlocal answered
            if read.timed_out:
                return  # the app's answer to a failed read; the 408 below goes instead
            answered = answered or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, read.receive, guarded_send)
        except Exception:
            if not read.timed_out:
                raise
        if read.timed_out and not answered:
            client = scope.get("client") or ("?", 0)
            log.warning("%s %s: request body from %s:%s too slow (%d bytes in %.1f s); 408",
                        scope["method"], scope["path"], client[0], client[1], read.received, read.elapsed)  # fmt: skip
            detail = (
                f"the request body did not arrive in time ({read.received} bytes in {read.elapsed:.0f} s; "
                f"at most {self.timeout_s:g} s between two chunks and {self.timeout_s:g} s in all plus "
                f"1 s per {self.min_rate_bytes} bytes, BFIELDS_API_BODY_TIMEOUT_S); send the body at once"
            )
            answer = problem_response(
                "request-timeout", detail, scope["path"], headers={"Connection": "close"}
            )
            await answer(scope, read.receive, send)


class _Read:
    """One request's body reads, each bounded by what is left of the body's deadline."""

    def __init__(self, receive: Receive, timeout_s: float, min_rate_bytes: int) -> None:
        self._receive = receive
        self.timeout_s = timeout_s
        self.min_rate_bytes = min_rate_bytes
        self.received = 0
        self.started: float | None = None
        self.complete = False
        self.timed_out = False

    @property
    def elapsed(self) -> float:
        return 0.0 if self.started is None else time.monotonic() - self.started

    async def receive(self) -> Message:
        if self.complete:
            return await self._receive()
        if self.timed_out:
            raise BodyTimeout
        now = time.monotonic()
        if self.started is None:
            self.started = now
        allowed = self.timeout_s + self.received / self.min_rate_bytes - (now - self.started)
        try:
            message = await asyncio.wait_for(self._receive(), min(self.timeout_s, max(allowed, 0.0)))
        except TimeoutError:
            self.timed_out = True
            raise BodyTimeout from None
        if message["type"] == "http.request":
            self.received += len(message.get("body", b""))
            self.complete = not message.get("more_body", False)
        else:  # http.disconnect: nothing more will arrive
            self.complete = True
        return message
