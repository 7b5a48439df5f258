"""Submit, cancel and retry jobs and batches: the rules, over the records.

A submission is checked (`validation`), then stored in one transaction that holds its scenes'
rows (a scene deleted since the check is `Missing`), admits it against the tenant's bound
(`OverQuota` past it, exact under any number of API processes) and inserts the jobs with their
batch, links and Idempotency-Key rows: committed, a job waits in its tenant's queue
(`jobs.queue`); refused, nothing is left behind, so a client's retry never runs work twice.

Idempotency-Keys (the IETF draft's rule): a key is unique per tenant and endpoint and stands for
one request. Requests carrying the same key run one after another (a PostgreSQL session lock,
`Busy` after `KEY_LOCK_WAIT_S`); the same body again returns the first job or batch, another body
is `Invalid` naming the key. A batch item's key names its job across batches, so a re-run batch
file makes no job for an item it already made.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from datetime import UTC, datetime, timedelta
from typing import Any, TypeVar

import redis

from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.jobs.batches import BatchRecord
from bayesian_fields_service.jobs.model import JobRecord, JobState, job_digest
from bayesian_fields_service.jobs.queue import AdmissionRefused, Priority, TenantQuota, admission_limit
from bayesian_fields_service.jobs.refusals import Busy, Invalid, Missing, OverQuota
from bayesian_fields_service.jobs.store import JobStore, NewJobs
from bayesian_fields_service.jobs.validation import JobAsk, Validation, check_id, checked_callback
from bayesian_fields_service.live.metrics import JOB_KEY, read_histogram
from bayesian_fields_service.observability import tracing
from bayesian_fields_service.records.ids import BATCH_ID, JOB_ID, SCENE_ID, new_id
from bayesian_fields_service.records.locks import LockBusy, session_lock
from bayesian_fields_service.scenes.store import SceneStore

T = TypeVar("T")

#: How long a request waits for another request holding the same Idempotency-Key or batch retry.
KEY_LOCK_WAIT_S = 60.0


def _found(kind: str, ident: str, value: T | None) -> T:
    """`value`, or `Missing` naming what was asked for."""
    if value is None:
        raise Missing(f"{kind} {ident!r} not found")
    return value


def _key_reused(key: str, what: str) -> Invalid:
    return Invalid(
        f"Idempotency-Key {key!r} was first used with a different {what}; a key stands for one "
        "request: send a new key for a new request"
    )


@dataclass(frozen=True)
class BatchAsk:
    """What a client asks for one batch: its jobs and what they share."""

    items: list[JobAsk]
    priority: Priority = "bulk"
    callback_url: str | None = None
    body_sha256: str = ""  # the whole request body's digest (the batch's Idempotency-Key rule)


@dataclass(frozen=True)
class JobSubmitted:
    """A submitted job: its record, whether it is new, and the tenant's quota after it (None
    where nothing was stored: the earlier job of an Idempotency-Key)."""

    record: JobRecord
    created: bool
    quota: TenantQuota | None = None


@dataclass(frozen=True)
class BatchSubmitted:
    """A submitted batch: its row, its jobs in order (new and reused), how many are new, and the
    tenant's quota after it (None where no job was stored)."""

    batch: BatchRecord
    jobs: list[JobRecord]
    created: int
    quota: TenantQuota | None = None


@dataclass
class JobService:
    """The jobs domain for one process (its records, settings and Redis for live progress)."""

    settings: ServiceSettings
    jobs: JobStore
    scenes: SceneStore
    redis: redis.Redis

    # ---- reading -------------------------------------------------------------------------------
    def job(self, tenant: str, job_id: str) -> JobRecord:
        check_id("job", job_id, JOB_ID)
        return _found("job", job_id, self.jobs.get(tenant, job_id))

    def batch(self, tenant: str, batch_id: str) -> BatchRecord:
        check_id("batch", batch_id, BATCH_ID)
        return _found("batch", batch_id, self.jobs.load_batch(tenant, batch_id))

    def with_queue_position(self, record: JobRecord) -> JobRecord:
        """The record with its place in the tenant's queue and an estimated start while it waits:
        from the tenant's recent dispatch rate, else the mean job duration per dispatch slot."""
        if record.state != JobState.queued:
            return record
        position = self.jobs.queue.position(record.tenant, record.id, record.priority, record.created_at)
        if position is None:
            return record
        rate = self.jobs.queue.dispatch_rate(record.tenant)
        eta_s: float | None = position / rate if rate > 0 else None
        if eta_s is None and (h := self._job_durations()) and h[2]:
            eta_s = h[1] / h[2] * position / self.settings.max_active_jobs_per_tenant
        start = datetime.now(UTC) + timedelta(seconds=eta_s) if eta_s is not None else None
        return record.model_copy(update={"queue_position": position, "estimated_start": start})

    def _job_durations(self) -> tuple[list[tuple[str, float]], float, float] | None:
        """The succeeded jobs' duration histogram (Redis metrics; None while Redis is away: the
        estimate is a convenience, the answer does not wait for it)."""
        try:
            return read_histogram(self.redis, JOB_KEY.format(outcome="succeeded"))
        except redis.RedisError:
            return None

    # ---- submitting ----------------------------------------------------------------------------
    def submit_job(self, tenant: str, ask: JobAsk) -> JobSubmitted:
        """One job (`JobSubmitted`). With a key, the earlier job of that key."""
        key = ask.idempotency_key
        if not key:
            record = Validation(self.settings, self.scenes, tenant).job(ask)
            return JobSubmitted(record, True, self._store([record], NewJobs(scene_ids=[ask.scene_id])))
        digest = job_digest(ask.scene_id, ask.tasks, ask.parameters, ask.model_profile)
        with self._key_lock(tenant, "jobs", key):
            existing = self.jobs.idempotent_job(tenant, key)
            if existing is not None and existing[1] and existing[1] != digest:
                raise _key_reused(key, "scene, task list, parameters or model profile")
            if existing is not None and (earlier := self.jobs.get(tenant, existing[0])) is not None:
                return JobSubmitted(earlier, False)
            record = Validation(self.settings, self.scenes, tenant).job(ask)
            quota = self._store([record], NewJobs(digests={record.id: digest}, scene_ids=[ask.scene_id]))
            return JobSubmitted(record, True, quota)

    def submit_batch(self, tenant: str, ask: BatchAsk, idempotency_key: str | None) -> BatchSubmitted:
        """A batch (every item validated before any is stored); with a key, the earlier batch of
        that key (`created` 0, `jobs` empty: the caller reads its status from the row)."""
        if not ask.items:
            raise Invalid("the batch is empty: give items or scene_ids x task_lists")
        if len(ask.items) > self.settings.max_batch_jobs:
            raise Invalid(
                f"{len(ask.items)} jobs; at most {self.settings.max_batch_jobs} per batch (BFIELDS_MAX_BATCH_JOBS)"
            )
        keys = [i.idempotency_key for i in ask.items if i.idempotency_key]
        if len(set(keys)) != len(keys):
            raise Invalid("items: an idempotency_key appears twice in the batch")
        checked_callback(self.settings, ask.callback_url)  # a refused URL before any work
        for item in ask.items:  # before any lock: an id that cannot exist is a plain `Missing`
            check_id("scene", item.scene_id, SCENE_ID)
        if not idempotency_key:
            return self._new_batch(tenant, ask, None)
        with self._key_lock(tenant, "batches", idempotency_key):
            earlier = self.jobs.idempotent_batch(tenant, idempotency_key)
            if earlier is not None and earlier[1] and earlier[1] != ask.body_sha256:
                raise _key_reused(idempotency_key, "batch body")
            if earlier is not None and (batch := self.jobs.load_batch(tenant, earlier[0])) is not None:
                return BatchSubmitted(batch, [], 0)
            return self._new_batch(tenant, ask, idempotency_key)

    def _new_batch(self, tenant: str, ask: BatchAsk, batch_key: str | None) -> BatchSubmitted:
        batch_id = new_id(BATCH_ID)
        items = ask.items
        digests = [
            job_digest(None, i.tasks, i.parameters, i.model_profile) if i.idempotency_key else ""
            for i in items
        ]
        # Items whose idempotency key names an earlier job reuse it (a re-run batch file makes no job).
        known = self.jobs.idempotent_jobs(
            tenant, keys := [i.idempotency_key for i in items if i.idempotency_key]
        )
        for item, digest in zip(items, digests, strict=True):
            key = item.idempotency_key
            if key in known and known[key][1] and known[key][1] != digest:
                raise _key_reused(key, "item (tasks, parameters or model profile)")
        found = self.jobs.get_many(tenant, [known[k][0] for k in keys if k in known])
        validation = Validation(self.settings, self.scenes, tenant)
        records = []
        for item in items:
            earlier = found.get(known[item.idempotency_key][0]) if item.idempotency_key in known else None
            records.append(earlier if earlier is not None else validation.job(item, batch_id=batch_id))
        new = [r for r in records if r.batch_id == batch_id]
        batch = BatchRecord(id=batch_id, tenant=tenant, total=len(records), priority=ask.priority,
                            idempotency_key=batch_key, callback_url=checked_callback(self.settings, ask.callback_url))  # fmt: skip
        by_new = {r.id: d for r, d in zip(records, digests, strict=True) if r.batch_id == batch_id and d}
        quota = self._store(new, NewJobs(digests=by_new, batch=batch, batch_job_ids=[r.id for r in records],
                                         batch_digest=ask.body_sha256, scene_ids=[r.scene_id for r in new]))  # fmt: skip
        return BatchSubmitted(batch, records, len(new), quota)

    def retry_batch(self, tenant: str, batch_id: str) -> int:
        """Submit the batch's failed jobs again, each as a new job in its place (one retry of a
        batch at a time); returns how many were submitted."""
        self.batch(tenant, batch_id)
        with self._held(f"the retry of batch {batch_id!r}", tenant, "batch-retry", batch_id):
            batch = self.batch(tenant, batch_id)  # as it is now, under the lock
            if not batch.counts.get(JobState.failed.value):  # nothing to retry: no write
                return 0
            failed = [j for _, j in self.jobs.batch_jobs(batch, states=[JobState.failed.value])]
            validation = Validation(self.settings, self.scenes, tenant)
            again = [
                validation.job(JobAsk(j.scene_id, j.tasks, j.parameters, j.model_profile, j.priority,
                                      None, j.idempotency_key), batch_id=batch.id).model_copy(update={"retry_of": j.id})
                for j in failed
            ]  # fmt: skip
            digests = {r.id: job_digest(None, r.tasks, f.parameters, r.model_profile)
                       for r, f in zip(again, failed, strict=True) if r.idempotency_key}  # fmt: skip
            self._store(again, NewJobs(digests=digests, retry_in=batch.id,  # each item's key -> its new job
                                       scene_ids=[r.scene_id for r in again]))  # fmt: skip
            return len(again)

    def _store(self, records: Sequence[JobRecord], new: NewJobs) -> TenantQuota | None:
        """The one transaction of a submission (module docstring), admitted against the tenant's
        bound; the tenant's quota after it (None where there was nothing to store)."""
        if not records:
            return None
        if (traceparent := tracing.current_traceparent()) is not None:  # the job's trace starts here
            records = [r.model_copy(update={"traceparent": traceparent}) for r in records]
            tracing.annotate({"bfields.jobs": len(records), "bfields.job_id": records[0].id,
                              "bfields.tenant": records[0].tenant})  # fmt: skip
        s = self.settings
        limit = admission_limit(s.max_waiting_jobs_per_tenant, s.max_active_jobs_per_tenant)
        try:
            used = self.jobs.create_many(list(records), replace(new, admit_limit=limit))
        except AdmissionRefused as refused:
            raise OverQuota(
                f"{refused.active} jobs are waiting or running; at most {limit} are allowed per tenant "
                f"({s.max_waiting_jobs_per_tenant} waiting, BFIELDS_MAX_WAITING_JOBS_PER_TENANT, beyond "
                f"{s.max_active_jobs_per_tenant} dispatched, BFIELDS_MAX_ACTIVE_JOBS_PER_TENANT); this "
                f"request needs {len(records)}",
                retry_after_s=s.retry_after_s,
                quota=TenantQuota(limit, refused.active),
            ) from None
        return TenantQuota(limit, used) if used is not None else None

    # ---- cancelling ----------------------------------------------------------------------------
    def cancel_job(self, tenant: str, job_id: str) -> JobRecord:
        """Cancel a job: a waiting one at once, a running one at its next frame (its worker is
        told through the cancel flag; the row's `cancel_requested` is the truth)."""
        self.job(tenant, job_id)
        record = self.jobs.request_cancel(tenant, job_id)
        if record is None:
            raise Missing(f"job {job_id!r} not found")
        return record

    def cancel_batch(self, tenant: str, batch_id: str) -> BatchRecord:
        """Cancel every unfinished job of a batch: one UPDATE; returns the batch as it is after."""
        self.batch(tenant, batch_id)
        self.jobs.cancel_batch(tenant, batch_id)
        return self.batch(tenant, batch_id)

    # ---- locks ---------------------------------------------------------------------------------
    @contextmanager
    def _held(self, what: str, *names: str) -> Iterator[None]:
        """A PostgreSQL session lock on `names` (`records.locks`): requests that must not overlap
        run one after another; `Busy` past the wait."""
        try:
            with session_lock(self.jobs.database, *names, wait_s=KEY_LOCK_WAIT_S):
                yield
        except LockBusy:
            raise Busy(f"{what} is being handled by another request; retry when it has finished") from None

    def _key_lock(self, tenant: str, endpoint: str, key: str) -> Any:
        return self._held(f"a request with Idempotency-Key {key!r}", tenant, f"idempotency:{endpoint}", key)


def body_digest(body_json: str) -> str:
    """sha256 of a request body as the batch's Idempotency-Key row keeps it."""
    return hashlib.sha256(body_json.encode()).hexdigest()
