"""One callback POST: to the address that was checked, within one deadline, reading a bounded answer.

httpx's timeouts are per operation (a receiver sending one byte per read timeout never times
out), and httpx resolves the name itself (a second DNS answer, possibly not the one checked). So
the POST goes through httpcore with a custom network backend (httpcore's documented extension
point, https://www.encode.io/httpcore/network-backends/):

- `connect_tcp` ignores what the URL's name resolves to and connects to the one address
  `callback_destinations.resolve_checked` approved; the URL keeps the name, so the Host header,
  TLS SNI and certificate verification are for the name, as with an ordinary request;
- every socket operation (connect, TLS handshake, each write, each read, headers included) gets
  at most the time left until one absolute deadline, and none starts once it has passed, so the
  attempt as a whole is bounded however the receiver paces its bytes;
- the answer's body is read up to `max_bytes` and the connection is then closed (a 400 MB answer
  costs one bounded buffer, not 400 MB).

Every attempt uses its own connection (no pool shared between names: a kept-alive TLS connection
verified for one name must not carry a request for another name on the same address). Redirects
are never followed: httpcore has none.
"""

from __future__ import annotations

import ssl
import time
import typing
from collections.abc import Iterable
from dataclasses import dataclass

import httpcore
import httpx

from bayesian_fields_service.webhooks.callback_destinations import Destination, IPAddress

#: The failures of one attempt (httpcore has no common base class for them).
TRANSPORT_ERRORS: tuple[type[Exception], ...] = (
    httpcore.TimeoutException,
    httpcore.NetworkError,
    httpcore.ProtocolError,
    httpcore.UnsupportedProtocol,
    httpcore.ConnectionNotAvailable,
    ssl.SSLError,
    OSError,
)
_EXCERPT_BYTES = 200


class _Deadline:
    """Seconds left until one monotonic instant, as each socket operation's timeout."""

    def __init__(self, at: float) -> None:
        self.at = at

    def clamp(self, timeout: float | None, error: type[Exception]) -> float:
        left = self.at - time.monotonic()
        if left <= 0:
            raise error("the callback attempt's deadline has passed")
        return left if timeout is None else min(timeout, left)


class _DeadlineStream(httpcore.NetworkStream):
    """A connection whose every read, write and TLS handshake ends by the deadline."""

    def __init__(self, inner: httpcore.NetworkStream, deadline: _Deadline) -> None:
        self._inner = inner
        self._deadline = deadline

    def read(self, max_bytes: int, timeout: float | None = None) -> bytes:
        return self._inner.read(max_bytes, self._deadline.clamp(timeout, httpcore.ReadTimeout))

    def write(self, buffer: bytes, timeout: float | None = None) -> None:
        self._inner.write(buffer, self._deadline.clamp(timeout, httpcore.WriteTimeout))

    def close(self) -> None:
        self._inner.close()

    def start_tls(
        self, ssl_context: ssl.SSLContext, server_hostname: str | None = None, timeout: float | None = None
    ) -> httpcore.NetworkStream:
        left = self._deadline.clamp(timeout, httpcore.ConnectTimeout)
        return _DeadlineStream(self._inner.start_tls(ssl_context, server_hostname, left), self._deadline)

    def get_extra_info(self, info: str) -> typing.Any:
        return self._inner.get_extra_info(info)


class PinnedBackend(httpcore.NetworkBackend):
    """Connects to `address` whatever the URL's host resolves to, within the deadline; refuses
    any other host than `host` (a request this backend was not made for)."""

    def __init__(self, host: str, address: IPAddress, deadline: _Deadline) -> None:
        self._host = host
        self._address = address
        self._deadline = deadline
        self._system = httpcore.SyncBackend()

    def connect_tcp(
        self,
        host: str,
        port: int,
        timeout: float | None = None,
        local_address: str | None = None,
        socket_options: Iterable[httpcore.SOCKET_OPTION] | None = None,
    ) -> httpcore.NetworkStream:
        if host != self._host:
            raise httpcore.ConnectError(f"pinned to {self._host}, asked for {host}")
        stream = self._system.connect_tcp(
            str(self._address), port, self._deadline.clamp(timeout, httpcore.ConnectTimeout),
            local_address, socket_options,
        )  # fmt: skip
        return _DeadlineStream(stream, self._deadline)

    def connect_unix_socket(
        self,
        path: str,
        timeout: float | None = None,
        socket_options: Iterable[httpcore.SOCKET_OPTION] | None = None,
    ) -> httpcore.NetworkStream:
        raise httpcore.ConnectError("callbacks never use Unix sockets")

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)


@dataclass(frozen=True)
class Answer:
    """What a receiver answered: the status, how much of the body was read, and its start."""

    status: int
    body_bytes_read: int
    truncated: bool  # the body was longer than the cap, or the deadline came first: cut off
    excerpt: bytes


_SSL_CONTEXT: ssl.SSLContext | None = None


def _ssl_context() -> ssl.SSLContext:
    """httpx's default verification (certifi's roots), made once: building it reads the bundle."""
    global _SSL_CONTEXT
    if _SSL_CONTEXT is None:
        _SSL_CONTEXT = httpx.create_ssl_context()
    return _SSL_CONTEXT


def post(
    dest: Destination,
    address: IPAddress,
    body: bytes,
    headers: dict[str, str],
    *,
    deadline: float,
    max_bytes: int,
) -> Answer:
    """POST `body` to `dest` over a connection to `address`, all of it done by `deadline`
    (`time.monotonic()` seconds); raises one of `TRANSPORT_ERRORS` when it cannot."""
    limit = _Deadline(deadline)
    left = limit.clamp(None, httpcore.ConnectTimeout)
    url = httpcore.URL(scheme=dest.scheme.encode(), host=dest.host.encode(), port=dest.port,
                       target=dest.target.encode())  # fmt: skip
    wire = [(b"Host", dest.authority.encode())] + [(k.encode(), v.encode()) for k, v in headers.items()]
    timeouts = {"connect": left, "read": left, "write": left, "pool": left}
    with (
        httpcore.ConnectionPool(
            ssl_context=_ssl_context() if dest.scheme == "https" else None,
            max_connections=1,
            max_keepalive_connections=0,
            network_backend=PinnedBackend(dest.host, address, limit),
        ) as pool,
        pool.stream("POST", url, headers=wire, content=body, extensions={"timeout": timeouts}) as resp,
    ):
        read, truncated, excerpt = 0, False, b""
        try:
            for chunk in resp.iter_stream():
                if len(excerpt) < _EXCERPT_BYTES:
                    excerpt += chunk[: _EXCERPT_BYTES - len(excerpt)]
                read += len(chunk)
                if read >= max_bytes or time.monotonic() >= deadline:
                    truncated = True
                    break
        except TRANSPORT_ERRORS:  # the status came: the receiver answered; the rest is not needed
            truncated = True
        return Answer(resp.status, read, truncated, excerpt)
