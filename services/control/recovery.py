"""Put back in the queue the dispatched jobs that Redis or a dead worker lost.

A waiting job cannot be lost: it is a row (`common.job_queue`). What can be lost is a dispatched
job's stage message: Redis restarted without its data, or a worker took the message and died
before it took the stage lock (the message then sits in the broker's unacknowledged hash until
the visibility timeout, hours), or the dispatcher died between the stamp and the send. Such a job
is *orphaned*: its row is dispatched and unfinished, no lock on any of its stages is held, and no
message of it waits in a Celery queue (or Redis has no live hash of it, or its hash says a stage
executes while no lock is held: a SIGKILLed worker, found once its lock expired, a minute, not
after the broker's visibility timeout).

An orphan is requeued (`JobQueue.requeue`: its dispatch stamp cleared, so it is the front of its
tenant's queue and the dispatcher sends its remaining stages within the tenant's bound) only
after it has looked orphaned for `recovery_grace_s` on two scans: a worker that is running a stage
re-creates its lock within one heartbeat, and a chain between two stages has its next message
queued within moments, so a live job is never sent twice. Should a duplicate slip through anyway,
stages are idempotent (finished markers are skipped) and guarded by the per-stage lock, so the
cost is time, never a wrong result.

Run by the control process's leader only, so the first-seen times of suspects live in its memory
(a new leader starts them afresh, which only delays a requeue by one grace period).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from bayesian_fields_service.common.jobs import JobStore
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.live.broker import jobs_with_queued_messages
from bayesian_fields_service.live.redis_keys import stage_lock_pattern
from bayesian_fields_service.records.leases import Fence, LeaseLost

log = logging.getLogger(__name__)


@dataclass
class Recovery:
    """The orphan scan (module docstring) with its suspects' first-seen times."""

    jobs: JobStore
    settings: ServiceSettings
    fence: Callable[[], Fence | None] = lambda: None
    suspects: dict[tuple[str, str], float] = field(default_factory=dict)

    def scan(self, *, grace_s: float | None = None) -> list[str]:
        """One scan; returns the ids of the jobs it put back in the queue."""
        grace_s = self.settings.recovery_grace_s if grace_s is None else grace_s
        client = self.jobs.redis
        now = time.time()
        queued: set[str] | None = None
        requeued: list[str] = []
        seen: set[tuple[str, str]] = set()
        for tenant, job_id in self.jobs.queue.dispatched_jobs():
            if any(True for _ in client.scan_iter(match=stage_lock_pattern(tenant, job_id), count=100)):
                continue  # a worker runs one of its stages
            if self.jobs.live_phase(tenant, job_id) == "waiting":
                if queued is None:  # read once per scan, and only when a job needs it
                    queued = jobs_with_queued_messages(
                        client, {self.settings.gpu_queue, self.settings.cpu_queue}
                    )
                if job_id in queued:
                    continue  # its next message waits for a worker
            pair = (tenant, job_id)
            seen.add(pair)
            first_seen = self.suspects.setdefault(pair, now)
            if first_seen == now and grace_s > 0 or now - first_seen < grace_s:
                continue
            try:
                moved = self.jobs.queue.requeue(tenant, job_id, self.fence())
            except LeaseLost as exc:  # another replica leads now: its own scan takes over
                log.warning("recovery scan stopped: %s", exc)
                break
            if moved:
                requeued.append(job_id)
                log.warning("requeued orphaned job %s/%s (no stage lock, no queued message)", tenant, job_id)
            seen.discard(pair)
        self.suspects = {p: t for p, t in self.suspects.items() if p in seen}
        return requeued
