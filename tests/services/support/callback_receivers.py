"""Real callback receivers for the delivery tests: HTTP/1.1 servers on 127.0.0.1, each in its own
thread pool and on its own port (one port = one destination for the per-destination bound), each
with one behaviour an attacker or a broken receiver might have:

- ``ok``       answers 204 at once (the ordinary receiver);
- ``drip``     sends its answer one byte every `drip_s` seconds, forever (a per-read timeout never
               fires; only a deadline for the whole attempt ends it);
- ``huge``     answers 200 with a `body_bytes` body (hundreds of MB), streamed as fast as the
               client reads (reading it whole is what grew the worker by 791 MiB);
- ``silent``   reads the request and never answers;
- ``redirect`` answers 302 to `location` (which must never be requested);
- ``flaky``    answers 500 to an event's first attempt and 200 to the next.

Every request is recorded, under its body's ``event_id``, with when it started and when the
client went away, so a test can tell how long an attempt lasted, how many were in flight at
once, and whether one event was ever in flight twice.
"""

from __future__ import annotations

import json
import select
import socket
import threading
import time
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

BEHAVIOURS = ("ok", "drip", "huge", "silent", "redirect", "flaky")
_CHUNK = b"x" * (1024 * 1024)
_DRIP_ANSWER = (
    b"HTTP/1.1 200 OK\r\nContent-Type: text/plain\r\nContent-Length: 100000\r\n\r\n" + b"." * 100000
)


@dataclass
class Hit:
    """One request a receiver took: its event, when it came and ended, what was sent back."""

    event_id: str
    path: str
    headers: dict[str, str]
    body: bytes
    start: float  # time.monotonic() when the request (headers and body) had been read
    end: float | None = None  # when the answer was done or the client had gone
    sent: int = 0  # bytes of answer written
    status: int | None = None


@dataclass
class Receiver:
    """One real HTTP server with one behaviour (see the module's docstring)."""

    behaviour: str
    drip_s: float = 1.5
    body_bytes: int = 400 * 1024 * 1024
    location: str = ""
    hits: list[Hit] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)
    in_flight: int = 0
    max_in_flight: int = 0
    closing: threading.Event = field(default_factory=threading.Event)

    def __post_init__(self) -> None:
        assert self.behaviour in BEHAVIOURS, self.behaviour
        self.server = ThreadingHTTPServer(("127.0.0.1", 0), _handler_for(self))
        self.server.daemon_threads = True
        self.thread = threading.Thread(
            target=self.server.serve_forever, daemon=True, name=f"rx-{self.behaviour}"
        )
        self.thread.start()

    @property
    def port(self) -> int:
        return int(self.server.server_address[1])

    def url(self, path: str = "/cb", host: str = "127.0.0.1") -> str:
        return f"http://{host}:{self.port}{path}"

    def snapshot(self) -> list[Hit]:
        with self.lock:
            return list(self.hits)

    def events(self) -> list[str]:
        return [h.event_id for h in self.snapshot()]

    def close(self) -> None:
        self.closing.set()
        self.server.shutdown()
        self.server.server_close()

    # ---- bookkeeping, called by the handler ----------------------------------------------------
    def _begin(self, hit: Hit) -> bool:
        """Record `hit`; whether it is the first attempt of its event here."""
        with self.lock:
            first = all(h.event_id != hit.event_id for h in self.hits)
            self.hits.append(hit)
            self.in_flight += 1
            self.max_in_flight = max(self.max_in_flight, self.in_flight)
        return first

    def _end(self, hit: Hit) -> None:
        with self.lock:
            hit.end = time.monotonic()
            self.in_flight -= 1


def client_gone(sock: socket.socket, wait_s: float) -> bool:
    """Whether the client closed its end within `wait_s` (readable, and reading gives nothing)."""
    readable, _, _ = select.select([sock], [], [], wait_s)
    if not readable:
        return False
    try:
        return sock.recv(1, socket.MSG_PEEK) == b""
    except OSError:
        return True


def _event_id(body: bytes) -> str:
    """The body's ``event_id`` (every callback is a JSON object with one), "" for anything else."""
    try:
        event = json.loads(body)
    except ValueError:
        return ""
    return str(event.get("event_id", "")) if isinstance(event, dict) else ""


def _handler_for(rx: Receiver) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def do_POST(self) -> None:  # noqa: N802 - the http.server API
            body = self.rfile.read(int(self.headers.get("Content-Length", "0")))
            hit = Hit(_event_id(body), self.path, dict(self.headers), body, time.monotonic())
            first = rx._begin(hit)
            self.connection.settimeout(30)  # a client that neither reads nor closes cannot hang us
            try:
                getattr(self, "_" + rx.behaviour)(hit, first)
            except OSError:  # the client went away mid-answer: what a capped reader does
                pass
            finally:
                rx._end(hit)
                self.close_connection = True

        def _answer(self, hit: Hit, status: int, extra: dict[str, str] | None = None) -> None:
            hit.status = status
            self.send_response(status)
            for k, v in (extra or {}).items():
                self.send_header(k, v)
            self.send_header("Content-Length", "0")
            self.send_header("Connection", "close")
            self.end_headers()

        def _ok(self, hit: Hit, first: bool) -> None:
            self._answer(hit, 204)

        def _flaky(self, hit: Hit, first: bool) -> None:
            self._answer(hit, 500 if first else 200)

        def _redirect(self, hit: Hit, first: bool) -> None:
            self._answer(hit, 302, {"Location": rx.location})

        def _silent(self, hit: Hit, first: bool) -> None:
            while not rx.closing.is_set() and not client_gone(self.connection, 0.05):
                pass

        def _drip(self, hit: Hit, first: bool) -> None:
            hit.status = 200
            for i in range(len(_DRIP_ANSWER)):
                if rx.closing.is_set():
                    return
                self.connection.sendall(_DRIP_ANSWER[i : i + 1])
                hit.sent += 1
                if client_gone(self.connection, rx.drip_s):
                    return

        def _huge(self, hit: Hit, first: bool) -> None:
            hit.status = 200
            self.send_response(200)
            self.send_header("Content-Type", "application/octet-stream")
            self.send_header("Content-Length", str(rx.body_bytes))
            self.end_headers()
            self.wfile.flush()
            left = rx.body_bytes
            while left > 0 and not rx.closing.is_set():
                chunk = _CHUNK[: min(left, len(_CHUNK))]
                self.connection.sendall(chunk)
                hit.sent += len(chunk)
                left -= len(chunk)

        def log_message(self, format: str, *args: object) -> None:  # noqa: A002 - the base's name
            return

    return Handler


def overlapping(hits: list[Hit]) -> list[tuple[str, float, float]]:
    """Attempts of one event that were in flight at the same time: (event, start, other's end)."""
    found: list[tuple[str, float, float]] = []
    by_event: dict[str, list[Hit]] = {}
    for h in hits:
        by_event.setdefault(h.event_id, []).append(h)
    for event_id, attempts in by_event.items():
        attempts.sort(key=lambda h: h.start)
        for a, b in zip(attempts, attempts[1:], strict=False):
            if a.end is None or b.start < a.end:
                found.append((event_id, b.start, a.end if a.end is not None else float("inf")))
    return found


def rss_mib(pid: int) -> float:
    """Resident memory of process `pid` in MiB (from /proc)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for pid {pid}")


class RssSampler:
    """Samples a process's resident memory every `every_s` in a thread; `.peak` is the highest."""

    def __init__(self, pid: int, every_s: float = 0.02) -> None:
        self.pid = pid
        self.every_s = every_s
        self.baseline = rss_mib(pid)
        self.peak = self.baseline
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="rss-sampler")
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self.every_s):
            try:
                self.peak = max(self.peak, rss_mib(self.pid))
            except (OSError, RuntimeError):
                return

    def stop(self) -> float:
        """Stop sampling; the growth over the baseline at the peak, in MiB."""
        self._stop.set()
        self._thread.join(2)
        return self.peak - self.baseline
