"""The bulk lane: a child process of each API process that serves batch submissions.

Parsing, validating and storing a 5,000-job batch is about a second of Python in whichever process
does it. In the API process that second holds the interpreter lock that every other request of the
process needs, and on a loaded machine another tenant's `GET /v1/jobs` then waits for it: measured
with `bench/bench_batch_ops.py --other-tenant`, that tenant's p99 rose 12-22x during a submit when
the batch ran in a worker thread of the same process, and 1.1x when it ran in another process. So
each API process starts one child: the same app (same routes, keys, error answers), served by
uvicorn on a Unix socket only this API process knows, with the lane off in it. The API process
reads a batch's body and hands the request, headers and bytes unchanged, to the child, and hands
the child's answer back; everything else it answers itself.

Failure handling:

- The child is started with the app and given `START_TIMEOUT_S` to listen; a request that finds it
  not listening yet waits for it (the request never reached it, so waiting is safe).
- A child that died is started again by the next batch; a batch the child died *while* serving may
  or may not have been stored, so it is answered 503 with the advice to retry with the same
  Idempotency-Key (`bfields batch` sends one).
- A child that is frozen (SIGSTOP, a stalled host) or too loaded to answer is found out while a
  batch waits for it: the API process asks the child's `/healthz` beside the batch, and a ping not
  answered within `wait_s` (`BFIELDS_API_BULK_LANE_WAIT_S`, 10 s by default) answers the batch 503
  + Retry-After, instead of waiting `ANSWER_TIMEOUT_S`; the batch may still be stored when the
  child runs again, so the answer says to retry with the same Idempotency-Key. A child that answers
  its pings may take up to `ANSWER_TIMEOUT_S` with a fleet-sized batch.
- The child watches its parent and stops when the parent is gone (a SIGKILLed API process leaves
  no lane behind). It runs at a lower CPU priority (`NICENESS`), so on a busy machine other
  tenants' requests come first.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
from fastapi import Request, Response

log = logging.getLogger(__name__)

LANE_APP = "bayesian_fields_service.api.app:create_lane_app"
"""The child's app factory: the same app with the lane off, settled by `settle_child`."""

START_TIMEOUT_S = 60.0
"""How long a request waits for a (re)started child to listen (an import of the app takes 2-6 s
on a loaded 2-core machine)."""

NICENESS = 10
"""The child's CPU niceness: on a busy machine the kernel runs the API process (other tenants'
requests) before a batch's parsing, which may take a little longer instead."""

ANSWER_TIMEOUT_S = 600.0
"""The longest a batch may take in the child (a 50,000-job batch takes about 11 s here)."""

_HOP_HEADERS = frozenset({"host", "content-length", "connection", "transfer-encoding", "keep-alive"})
_ANSWER_DROPPED = frozenset({"content-length", "transfer-encoding", "connection", "date", "server"})


def _socket_path() -> Path:
    """This process's lane socket: in the temp folder, or in /tmp where the temp folder's path is
    too long for a Unix socket (108 bytes at most)."""
    name = f"bfields-bulk-{os.getpid()}.sock"
    path = Path(tempfile.gettempdir()) / name
    return path if len(str(path)) < 100 else Path("/tmp") / name


class LaneUnavailable(Exception):
    """The child could not serve the request (not listening in time, or died mid-request)."""


class BulkLane:
    """One child process serving the batch route for this API process (module docstring)."""

    def __init__(self, socket_path: Path | None = None, *, wait_s: float = 10.0) -> None:
        self.socket_path = socket_path or _socket_path()
        self.wait_s = wait_s
        self._process: subprocess.Popen[bytes] | None = None
        self._client: httpx.AsyncClient | None = None
        self._restart = threading.Lock()

    def start(self) -> None:
        """Start the child (returns at once; requests wait for it to listen)."""
        with self._restart:
            if self._process is not None and self._process.poll() is None:
                return
            self.socket_path.unlink(missing_ok=True)
            argv = [sys.executable, "-m", "uvicorn", "--factory", LANE_APP,
                    "--uds", str(self.socket_path), "--no-access-log", "--log-level", "warning"]  # fmt: skip
            self._process = subprocess.Popen(argv)  # this process's environment: its settings
            log.info("bulk lane started (pid %d, %s)", self._process.pid, self.socket_path)

    def stop(self, timeout_s: float = 10.0) -> None:
        """Stop the child gracefully (a batch in progress finishes), then for good."""
        process, self._process = self._process, None
        if process is not None and process.poll() is None:
            process.terminate()
            try:
                process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        self.socket_path.unlink(missing_ok=True)

    @property
    def pid(self) -> int | None:
        return self._process.pid if self._process is not None and self._process.poll() is None else None

    def _http(self) -> httpx.AsyncClient:
        if self._client is None:
            # a connection per batch, none kept alive: a request then never goes out on a
            # connection to a child that died since (it could not tell whether the batch arrived);
            # it fails to connect instead, which is safe to retry
            no_reuse = httpx.Limits(max_keepalive_connections=0)
            transport = httpx.AsyncHTTPTransport(uds=str(self.socket_path), limits=no_reuse)
            self._client = httpx.AsyncClient(transport=transport, base_url="http://bulk-lane",
                                             timeout=httpx.Timeout(ANSWER_TIMEOUT_S, connect=5.0))  # fmt: skip
        return self._client

    async def aclose(self) -> None:
        if self._client is not None:
            await self._client.aclose()
            self._client = None

    async def forward(self, request: Request, body: bytes) -> Response:
        """The child's answer to `request` (with `body`, already read), or `LaneUnavailable`: the
        child could not be reached, died while serving, or stopped answering its pings."""
        headers = [(k, v) for k, v in request.headers.raw if k.decode("latin-1").lower() not in _HOP_HEADERS]
        path = request.url.path + (f"?{request.url.query}" if request.url.query else "")
        sent = asyncio.create_task(self._send(request.method, path, headers, body))
        probe: asyncio.Task[bool] | None = None
        try:
            while not sent.done():
                probe = asyncio.create_task(self._alive())
                await asyncio.wait({sent, probe}, return_when=asyncio.FIRST_COMPLETED)
                if sent.done():
                    break
                if not probe.result():
                    log.warning("bulk lane: child pid %s answered no ping within %g s while serving %s %s",
                                self.pid, self.wait_s, request.method, path)  # fmt: skip
                    raise LaneUnavailable(
                        f"the batch intake did not answer within {self.wait_s:g} s (frozen or overloaded); "
                        "retry with the same Idempotency-Key: you get the batch if it was stored, a new "
                        "one if not"
                    )
                await asyncio.wait({sent}, timeout=min(1.0, self.wait_s))  # alive: look again soon
            answer = sent.result()
        finally:
            for task in (sent, probe):
                if task is not None and not task.done():
                    task.cancel()
                    with contextlib.suppress(BaseException):
                        await task
        kept = {k: v for k, v in answer.headers.items() if k.lower() not in _ANSWER_DROPPED}
        return Response(answer.content, status_code=answer.status_code, headers=kept)

    async def _alive(self) -> bool:
        """False when the child accepted a ping but did not answer it within `wait_s` (frozen or
        overloaded); True when it answered, or is not listening yet (starting: `_send` waits for
        it, bounded by `START_TIMEOUT_S`)."""
        try:
            await self._http().get("/healthz", timeout=self.wait_s)
        except (httpx.ConnectError, FileNotFoundError):
            await asyncio.sleep(min(1.0, self.wait_s))
            return not _stopped(self.pid)  # frozen before it listened: not starting, stopped
        except httpx.TransportError:
            return False
        return True

    async def _send(
        self, method: str, path: str, headers: list[tuple[bytes, bytes]], body: bytes
    ) -> httpx.Response:
        """The request sent to the child, once it listens (the child started again if it died)."""
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if self._process is None or self._process.poll() is not None:
                await self.aclose()  # its pooled connections went with the old child
                await asyncio.to_thread(self.start)  # died (or never started): start it again
            try:
                return await self._http().request(method, path, headers=headers, content=body)
            except (httpx.ConnectError, FileNotFoundError):
                if time.monotonic() > deadline:  # never reached the child: nothing was stored
                    raise LaneUnavailable("the batch intake did not start in time; retry") from None
                await asyncio.sleep(0.05)
            except httpx.TransportError as exc:
                log.warning("bulk lane: %s while serving %s %s (child pid %s, exit %s)", type(exc).__name__,
                            method, path, self._process.pid if self._process else None,
                            self._process.poll() if self._process else None)  # fmt: skip
                raise LaneUnavailable(
                    "the batch intake stopped while serving this batch; retry with the same "
                    "Idempotency-Key to get the batch if it was stored, or a new one if not"
                ) from None


def _stopped(pid: int | None) -> bool:
    """True when process `pid` is stopped (SIGSTOP, a debugger): its state in /proc is T or t.
    False where /proc is not there to say."""
    if pid is None:
        return False
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[-1].split()[:1] in (["T"], ["t"])


def settle_child() -> None:
    """In the child, as it starts: lower its CPU priority (`NICENESS`), and stop it (SIGTERM to
    itself, so uvicorn shuts down cleanly) once the API process that started it is gone."""
    parent = os.getppid()
    os.nice(NICENESS)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        log.warning("bulk lane: API process %s is gone; stopping", parent)
        with contextlib.suppress(ProcessLookupError):
            os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="bf-bulk-lane-parent", daemon=True).start()
