"""Enqueue a job's stages as a Celery chain, by task name; and the dispatcher that does it.

Kept apart from `tasks.py` so the API can enqueue without importing the pipeline (torch, models):
it only needs the task names and queues, which the stage table (`job.stage_table`) gives. The chain is perceive -> fuse on the GPU queue, then
cluster on the CPU queue; a resumed job sends only its unfinished stages. Submitted jobs wait in
their tenant's fair-share queue (`common.fair_queue`) until the `Dispatcher` sends them here.
"""

from __future__ import annotations

import base64
import contextlib
import json
import logging
import os
import re
import secrets
import socket
import threading
from collections.abc import Iterable, Sequence

import redis
from celery import Celery, chain

from bayesian_fields_core.job.stage_table import stage as stage_spec
from bayesian_fields_service.common.fair_queue import FairQueue, choose
from bayesian_fields_service.common.jobs import JobStore, id_age_s
from bayesian_fields_service.common.settings import ServiceSettings
from bayesian_fields_service.worker.metrics import observe_queue_wait

log = logging.getLogger(__name__)


def queue_for(stage: str, gpu_queue: str, cpu_queue: str) -> str:
    """The queue of `stage`: its table row says "gpu" or "cpu"; the names come from the settings."""
    return gpu_queue if stage_spec(stage).queue == "gpu" else cpu_queue


def enqueue_stages(
    app: Celery, tenant: str, job_id: str, stages: Sequence[str], *, gpu_queue: str, cpu_queue: str
) -> None:
    """Send the chain of `stages` (in order) for one job. Arguments are plain JSON."""
    if not stages:
        return
    sigs = [
        app.signature(
            stage_spec(stage).task_name,
            args=(tenant, job_id),
            immutable=True,
            queue=queue_for(stage, gpu_queue, cpu_queue),
        )
        for stage in stages
    ]
    chain(*sigs).apply_async()


#: Celery's Redis transport keeps one list per priority step of a queue (priority 0 = the name).
PRIORITY_SUFFIXES = ("", "\x06\x163", "\x06\x166", "\x06\x169")

#: A job id as it appears in a stage message (the task's arguments, `argsrepr` in its headers).
_JOB_ID = re.compile(rb"j_[0-9a-f]{22}")


def queue_length(client: redis.Redis, queue: str) -> int:
    """Messages waiting in a Celery queue on the Redis broker (not those a worker reserved)."""
    pipe = client.pipeline()
    for sfx in PRIORITY_SUFFIXES:
        pipe.llen(queue + sfx)
    return int(sum(pipe.execute()))


def jobs_with_queued_messages(client: redis.Redis, queues: Iterable[str]) -> set[str]:
    """Ids of the jobs that have a stage message waiting in one of `queues` (any priority list).

    Recovery needs it to tell a dispatched job whose message still waits for a worker from one
    whose message a worker took and then died with (before it took the stage lock): the second
    is in no list, holds no lock, and without this check would wait for the broker's visibility
    timeout (hours). The lists are short (the dispatcher keeps the GPU queue a few messages deep;
    the CPU queue holds at most one message per dispatched job), so reading them whole is cheap."""
    pipe = client.pipeline()
    for queue in queues:
        for sfx in PRIORITY_SUFFIXES:
            pipe.lrange(queue + sfx, 0, -1)
    found: set[str] = set()
    for messages in pipe.execute():
        for raw in messages:
            found.update(m.decode() for m in _JOB_ID.findall(_message_text(raw)))
    return found


def _message_text(raw: bytes) -> bytes:
    """A kombu message on the Redis transport (JSON) with its base64 body decoded beside it, so
    a job id is found whether the task's arguments sit in the headers or only in the body."""
    try:
        body = json.loads(raw).get("body", "")
        return raw + b"\n" + base64.b64decode(body)
    except (ValueError, TypeError, AttributeError):
        return raw


class Dispatcher:
    """Releases waiting jobs to the worker queues, fairly between tenants (see `fair_queue`).

    Every API process runs one in a daemon thread; a Redis lease lets one of them dispatch at a
    time (the others retry the lease each round and take over when a holder dies). A round tops
    the GPU queue up to `dispatch_queue_depth` messages: each job is moved atomically (Lua, fenced
    by the lease) from its tenant's waiting set to its dispatched set, then its manifest is read
    and its remaining stages are sent as one Celery chain. A crash after the move and before the
    send leaves the job ``phase=dispatching`` with no message: the workers' recovery scan puts it
    back at the front of its queue (`FairQueue.requeue`); a crash after the send at worst sends
    that chain twice, which the stage markers and locks make harmless (no stage runs twice)."""

    def __init__(self, app: Celery, jobs: JobStore, settings: ServiceSettings, client: redis.Redis) -> None:
        self.app = app
        self.jobs = jobs
        self.settings = settings
        self.client = client
        self.fair = FairQueue(client, settings.gpu_queue)
        self.token = f"{socket.gethostname()}:{os.getpid()}:{secrets.token_hex(6)}"
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def round(self) -> int:
        """One round: hold the lease, dispatch while the queue has room. Returns jobs sent."""
        s = self.settings
        if not self.fair.hold_lease(self.token, s.dispatcher_lease_s):
            return 0
        sent = 0
        full: set[str] = set()
        while True:
            room = s.dispatch_queue_depth - queue_length(self.client, s.gpu_queue)
            if room <= 0:
                return sent
            pick = choose(self.fair.backlog(), s.max_active_jobs_per_tenant, full)
            if pick is None:
                return sent
            code, job_id, _ = self.fair.move(pick.tenant, self.token, s.max_active_jobs_per_tenant,
                                             s.weight(pick.tenant))  # fmt: skip
            if code < 0:  # the lease moved to another process meanwhile
                return sent
            if code == 0 or job_id is None:
                full.add(pick.tenant)
                continue
            if self._send(pick.tenant, job_id):
                sent += 1

    def _send(self, tenant: str, job_id: str) -> bool:
        record = self.jobs.load(tenant, job_id)
        if record is None or record.state.terminal:  # cancelled (or gone) while it waited
            self.fair.release_dispatched(tenant, [job_id])
            return False
        if not record.stages_done and record.stage_runs == 0:
            observe_queue_wait(self.client, tenant, id_age_s(job_id))
        enqueue_stages(self.app, tenant, job_id, record.remaining_stages(),
                       gpu_queue=self.settings.gpu_queue, cpu_queue=self.settings.cpu_queue)  # fmt: skip
        self.fair.sent(tenant, job_id)
        return True

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                self.round()
            except Exception:  # keep dispatching whatever one round hit (Redis or the bucket down)
                log.exception("dispatcher round failed")
            self._stop.wait(self.settings.dispatch_interval_s)
        with contextlib.suppress(Exception):
            self.fair.release_lease(self.token)

    def start(self) -> Dispatcher:
        if self._thread is None or not self._thread.is_alive():
            self._stop.clear()
            self._thread = threading.Thread(target=self._loop, name="bf-dispatcher", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
