"""`bfields-service control`: the one process that runs the service's background loops.

Why a process of its own: the dispatcher used to run inside every API process, recovery and the
callback sender inside every worker and the bucket sweep in the API again, each elected its own
way. Now API processes serve HTTP only, workers run stages only, and every loop below runs in the
replica that leads (`leadership`: a lease row with a deadline and a fencing token); run two replicas for failover.

Loops (each a thread that acts only while this replica leads):
- dispatch, every `dispatch_interval_s`: `Dispatcher.round` (the fair-share queue in the table);
- recovery, every `recovery_interval_s`: `Recovery.scan` (dispatched jobs whose message was lost);
- sweep, every `orphan_sweep_interval_s`: the bucket's orphaned uploads and scene files;
- callbacks: the outbox sender (`webhooks.callbacks.CallbackSender`), started on taking the lead and
  stopped on losing it.
The usage of jobs that end without a worker (cancelled while waiting) needs no loop: it is written
in the transaction that ends them (`JobStore._queue_callbacks`).

Health on `control_port`: ``/healthz`` answers 200 while the election loop runs (a liveness probe:
a hung process is restarted), ``/readyz`` 200 while the records database answers; both bodies
say whether this replica leads.
"""

from __future__ import annotations

import json
import logging
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import redis

from bayesian_fields_service import hooks
from bayesian_fields_service.config.settings import ServiceSettings, apply_log_level, get_settings
from bayesian_fields_service.control.dispatcher import Dispatcher
from bayesian_fields_service.control.leadership import Leadership
from bayesian_fields_service.control.recovery import Recovery
from bayesian_fields_service.jobs.store import JobStore
from bayesian_fields_service.observability import logs, tracing
from bayesian_fields_service.records.database import open_records, ping
from bayesian_fields_service.scenes.bucket_sweep import sweep_bucket
from bayesian_fields_service.scenes.postgres import scene_store
from bayesian_fields_service.storage.stores import build_store, direct_transfers
from bayesian_fields_service.webhooks.callbacks import CallbackSender
from bayesian_fields_service.worker.celery_app import make_celery

log = logging.getLogger(__name__)

#: How often a loop of a replica that does not lead looks whether it leads now.
STANDBY_POLL_S = 0.5


@dataclass
class Loop:
    """One background loop: `work` every `interval_s` while `leads()` says so."""

    name: str
    interval_s: float
    work: Callable[[], Any]
    leads: Callable[[], bool]
    stop: threading.Event
    last_ok: float | None = None
    thread: threading.Thread | None = field(default=None, repr=False)

    def run(self) -> None:
        while not self.stop.is_set():
            if not self.leads():  # a standby: look again soon, so a new leader starts at once
                self.stop.wait(STANDBY_POLL_S)
                continue
            try:
                self.work()
                self.last_ok = time.time()
            except redis.RedisError as exc:  # an outage, not a bug: one line per round
                log.warning("control loop %s: Redis unavailable (%s)", self.name, exc)
            except Exception:  # keep going whatever one round hit (the bucket, the database)
                log.exception("control loop %s failed", self.name)
            self.stop.wait(self.interval_s)

    def start(self) -> None:
        self.thread = threading.Thread(target=self.run, name=f"bf-control-{self.name}", daemon=True)
        self.thread.start()


class ControlProcess:
    """The election loop, the leader's loops and the health server of one replica."""

    def __init__(self, settings: ServiceSettings) -> None:
        self.settings = settings
        self.store = build_store(settings)
        self.redis = redis.Redis.from_url(settings.redis_url, socket_timeout=10, socket_connect_timeout=5)
        self.database = open_records(settings.database_url, migrate_first=settings.migrate_on_start)
        self.jobs = JobStore(self.store, self.redis, self.database)
        self.scenes = scene_store(self.database)
        self.leadership = Leadership(self.database, lease_ttl_s=settings.control_lease_ttl_s)
        self.stop = threading.Event()
        self.alive_at = time.time()
        self._callbacks: CallbackSender | None = None
        fence = lambda: self.leadership.fence  # noqa: E731
        dispatcher = Dispatcher(make_celery(settings), self.jobs, settings, self.redis, fence)
        recovery = Recovery(self.jobs, settings, fence)
        leads = lambda: self.leadership.held  # noqa: E731
        self.loops = [
            Loop("dispatch", settings.dispatch_interval_s, dispatcher.round, leads, self.stop),
            Loop("recovery", settings.recovery_interval_s, recovery.scan, leads, self.stop),
            Loop("sweep", settings.orphan_sweep_interval_s, self._sweep, leads, self.stop),
        ]

    def _sweep(self) -> None:
        if direct_transfers(self.store) is None:
            return  # a local folder: no multipart uploads, and uploads write the row last
        report = sweep_bucket(self.store, self.scenes, self.settings.orphan_max_age_s)
        if report.aborted_uploads or report.deleted_prefixes:
            log.warning("orphan sweep: aborted %d multipart uploads, deleted %d scene prefixes: %s %s",
                        len(report.aborted_uploads), len(report.deleted_prefixes),
                        report.aborted_uploads, report.deleted_prefixes)  # fmt: skip

    def _lead_changed(self, leads: bool) -> None:
        if leads:
            log.warning("this control replica leads now")
            self._callbacks = CallbackSender(self.database, self.settings)
            self._callbacks.start()
        else:
            log.warning("this control replica no longer leads")
            if self._callbacks is not None:
                self._callbacks.stop()
                self._callbacks = None

    def run(self) -> None:
        """Elect, lead or stand by until `stop` is set (SIGTERM / SIGINT), then resign."""
        for loop in self.loops:
            loop.start()
        led = False
        while not self.stop.is_set():
            leads = self.leadership.check()
            if leads != led:
                self._lead_changed(leads)
                led = leads
            self.alive_at = time.time()
            self.stop.wait(self.settings.control_election_interval_s)
        if led:
            self._lead_changed(False)
        self.leadership.resign()

    # ---- health --------------------------------------------------------------------------------
    def health(self) -> tuple[int, dict[str, Any]]:
        stale = time.time() - self.alive_at > 10 * self.settings.control_election_interval_s + 30
        body = {
            "leader": self.leadership.held,
            "lease_token": self.leadership.token,
            "loops": {lp.name: lp.last_ok for lp in self.loops},
        }
        return (503 if stale else 200), body

    def ready(self) -> tuple[int, dict[str, Any]]:
        try:
            ping(self.database)
        except Exception as exc:  # any failure to reach the database: not ready
            return 503, {"leader": self.leadership.held, "error": type(exc).__name__}
        return 200, {"leader": self.leadership.held}


def serve_health(control: ControlProcess, port: int, host: str = "127.0.0.1") -> ThreadingHTTPServer:
    """/healthz and /readyz on `host`:`port` (0: a free one) in a daemon thread; returns the
    server. Loopback unless the `control_host` setting opens it (the images set 0.0.0.0, where a
    probe reaches the pod's address)."""

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 (the http.server API)
            routes = {"/healthz": control.health, "/readyz": control.ready}
            if self.path not in routes:
                self.send_error(404)
                return
            code, body = routes[self.path]()
            data = json.dumps(body).encode()
            self.send_response(code)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        def log_message(self, *_: Any) -> None:  # probes every few seconds: keep the log for events
            return

    server = ThreadingHTTPServer((host, port), Handler)
    threading.Thread(target=server.serve_forever, name="bf-control-health", daemon=True).start()
    return server


def main() -> int:
    """The `bfields-service control` command."""
    settings = get_settings()
    apply_log_level(settings)
    hooks.install(settings)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logs.configure(settings)
    tracing.configure(settings, "control")
    control = ControlProcess(settings)
    server = serve_health(control, settings.control_port, settings.control_host)
    log.warning("control process ready (health on %s:%d)", settings.control_host, server.server_address[1])
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: control.stop.set())
    try:
        control.run()
    finally:
        server.shutdown()
    return 0
