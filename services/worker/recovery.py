"""Re-enqueue jobs that Redis forgot (a Redis restart without persistence loses every queued
message and every live hash, but the job rows in the records database remain).

A job is *orphaned* when its row is queued/running, no lock on any of its stages is held, and Redis either has no live hash for it (Redis
lost it) or its hash says a stage is executing (phase 'active': the worker died and its lock
expired). The second case recovers a SIGKILLed worker's job after the lock TTL (a minute) rather
than after the broker's visibility timeout (hours). A third case is a job the
dispatcher moved to its tenant's dispatched set and died before sending (phase 'dispatching').
A fourth is a job in phase 'waiting' that is neither in its tenant's fair-share queue nor has a
stage message in a Celery queue: a worker took its message and died before taking the stage lock
(the message sits in the broker's unacknowledged hash until the visibility timeout).
An orphan goes back to the front of its tenant's fair-share queue (`FairQueue.requeue`), so the
dispatcher resends it within the tenant's dispatch bound. A job is requeued
only after it has looked orphaned for `grace_s` seconds on two scans: a worker that is running a
stage re-creates its lock within one heartbeat, so a live job is never sent twice. Should a
duplicate slip through anyway, stages are idempotent (finished markers are skipped) and guarded
by the per-stage lock, so the cost is time, never a wrong result.

Two repairs ride on the same scan. A job whose row is not yet `submitted` after `grace_s` was stored
by an API that stopped (died, or lost Redis) between storing it and confirming its enqueue. The
job is complete and valid (the API validated it and took its quota slot before storing it), so a
batch service runs it: the scan submits it to the tenant's fair-share queue itself, as long as
its row is still queued with no stage done, and marks it submitted. A job that already waits
in the fair-share queue or was dispatched counts as submitted: `FairQueue.submit` leaves it
alone (one Lua script checks both), so it is never queued, run or listed twice.
A client that retries with the same Idempotency-Key gets this job back (the key's row is inserted
with the job's, before the enqueue); one that retries without a key asked for a second job. And each
tenant's quota set is made to agree with the active rows (`TenantQuota.repair`), so a
Redis wipe or a crash never leaks or loses a slot for long.

Every worker runs the scan in a daemon thread (started on `worker_ready`); a Redis lock makes
one scan at a time do the work.
"""

from __future__ import annotations

import threading
import time

import redis
from celery import Celery
from celery.utils.log import get_logger

from bayesian_fields_service.common.fair_queue import FairQueue, dispatched_key
from bayesian_fields_service.common.jobs import JobState, JobStore, id_age_s
from bayesian_fields_service.common.settings import ServiceSettings
from bayesian_fields_service.worker.dispatch import jobs_with_queued_messages

log = get_logger(__name__)  # a child of the 'celery' logger: lands in the worker log

_SUSPECT_KEY = "bf:orphan:{tenant}:{job_id}"

_stop = threading.Event()
_thread: threading.Thread | None = None


def _has_stage_lock(client: redis.Redis, tenant: str, job_id: str) -> bool:
    return any(True for _ in client.scan_iter(match=f"bf:lock:{tenant}:{job_id}:*", count=100))


def recover_orphans(
    app: Celery, jobs: JobStore, settings: ServiceSettings, *, grace_s: float | None = None
) -> list[str]:
    """One scan; returns the ids of the jobs it re-enqueued. `grace_s` defaults to
    `settings.recovery_grace_s`."""
    grace_s = settings.recovery_grace_s if grace_s is None else grace_s
    client = jobs.redis
    # short expiry: a worker killed mid-scan must not block the other scanners for long
    lock = client.lock("bf:recovery", timeout=max(10.0, 4 * settings.recovery_interval_s), blocking_timeout=0)
    if not lock.acquire(blocking=False):
        return []
    requeued: list[str] = []
    fair = FairQueue(client, settings.gpu_queue)
    try:
        now = time.time()
        pending = _enqueue_unsubmitted(fair, jobs, grace_s, requeued)
        active = jobs.active_jobs()
        queued: set[str] | None = None
        _repair_quotas(jobs, active, grace_s)
        for tenant, job_id in active:
            if (tenant, job_id) in pending:  # stored, not yet enqueued: the API is on it (or died)
                continue
            # Healthy: running (a stage lock is held), or waiting where something will pick it
            # up: in its tenant's fair-share queue, or as a stage message in a Celery queue. A
            # job in phase 'waiting' that is in neither had its message taken by a worker that
            # died before it took the stage lock: without this it would wait for the broker's
            # visibility timeout (hours).
            if _has_stage_lock(client, tenant, job_id):
                continue
            if jobs.live_phase(tenant, job_id) == "waiting":
                if fair.position(tenant, job_id) is not None:
                    continue
                if queued is None:  # read once per scan, and only when a job needs it
                    queued = jobs_with_queued_messages(client, {settings.gpu_queue, settings.cpu_queue})
                if job_id in queued:
                    continue
            suspect = _SUSPECT_KEY.format(tenant=tenant, job_id=job_id)
            first_seen = client.get(suspect)
            if first_seen is None:
                client.set(suspect, now, ex=int(grace_s * 10) + 60)
                if grace_s > 0:
                    continue
            elif now - float(first_seen) < grace_s:
                continue
            record = jobs.load(tenant, job_id)
            if record is None or record.state.terminal:  # ended since the scan read the rows
                continue
            fair.requeue(tenant, record.priority, job_id)  # phase 'waiting' again, front of its queue
            client.delete(suspect)
            requeued.append(job_id)
            log.warning("requeued orphaned job %s/%s at stages %s", tenant, job_id, record.remaining_stages())
    finally:
        try:
            lock.release()
        except redis.RedisError:
            pass
    return requeued


def _enqueue_unsubmitted(
    fair: FairQueue, jobs: JobStore, grace_s: float, requeued: list[str]
) -> set[tuple[str, str]]:
    """Submit the jobs whose submission never confirmed it (unsubmitted past `grace_s`) to the
    fair-share queue, appending their ids to `requeued`; a job already waiting there or
    dispatched is only marked submitted.

    Returns the (tenant, job id) still pending but younger than `grace_s` (left to the API)."""
    waiting: set[tuple[str, str]] = set()
    for tenant, job_id in jobs.pending_jobs():
        # Age from the id (it starts with its creation time): a young unsubmitted job is one whose
        # API is enqueueing it right now and must be left alone.
        if id_age_s(job_id) < grace_s:
            waiting.add((tenant, job_id))
            continue
        record = jobs.load(tenant, job_id)
        if record is None or record.state.terminal:
            jobs.mark_submitted(tenant, [job_id])
            continue
        if record.state == JobState.queued and not record.stages_done and not fair.contains(tenant, job_id):
            jobs.touch_live(record)  # known to Redis (phase 'waiting') before it can be dispatched
            if fair.submit(tenant, record.priority, [job_id]):
                requeued.append(job_id)
                log.warning(
                    "submitted job %s/%s: stored by an API that stopped before submitting it", tenant, job_id
                )
        jobs.mark_submitted(tenant, [job_id])  # submitted now, or it already was
    return waiting


def _repair_quotas(jobs: JobStore, active: list[tuple[str, str]], grace_s: float) -> None:
    """Admission sets re-take active jobs and drop finished ones; dispatched sets only drop members
    whose job is no longer active (a lost member is re-added by requeue and dispatch)."""
    by_tenant: dict[str, set[str]] = {}
    for tenant, job_id in active:
        by_tenant.setdefault(tenant, set()).add(job_id)
    for tenant in set(by_tenant) | set(jobs.quota.tenants()):
        added, dropped = jobs.quota.repair(
            tenant, by_tenant.get(tenant, set()), older_than_s=max(grace_s, 30.0)
        )
        if added or dropped:
            log.warning("quota of %s repaired: %d slots re-taken, %d released", tenant, added, dropped)
        gone = jobs.quota.drop_stale(dispatched_key(tenant), by_tenant.get(tenant, set()),
                                     older_than_s=max(grace_s, 30.0))  # fmt: skip
        if gone:
            log.warning("dispatch bound of %s repaired: %d finished jobs released", tenant, gone)


def _loop(app: Celery, jobs: JobStore, settings: ServiceSettings, interval_s: float) -> None:
    while not _stop.is_set():
        try:
            recover_orphans(app, jobs, settings)
        except Exception:  # keep scanning whatever one scan hit (Redis down, bucket hiccup)
            log.exception("orphan recovery scan failed")
        _stop.wait(interval_s)


def start_recovery_thread(
    app: Celery, jobs: JobStore, settings: ServiceSettings, interval_s: float | None = None
) -> None:
    """Scan every `interval_s` (default `settings.recovery_interval_s`) in a daemon thread."""
    interval_s = settings.recovery_interval_s if interval_s is None else interval_s
    global _thread
    if _thread is not None and _thread.is_alive():
        return
    _stop.clear()
    _thread = threading.Thread(
        target=_loop, args=(app, jobs, settings, interval_s), name="bf-recovery", daemon=True
    )
    _thread.start()


def stop_recovery_thread() -> None:
    _stop.set()
