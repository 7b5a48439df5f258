"""The jobs domain's store: a job's row is the truth, the live port holds only progress.

Why two places: the records survive everything (a Redis restart, a redeploy), so a job is never
lost, while stage/progress updates arrive many times a second and belong in the live state. A read
merges the two: the row gives the record, the live hash overlays the stage and progress while the
job is active. Every write reads the row under its lock and applies `model.settle` (terminal
states sticky, cancel wins, fields accumulate), so the API's cancel and a worker's stage update,
serialised by the row lock, never lose each other's fields; the write that ends a job queues its
callback events and usage end row in the same unit of work (`_queue_ends`), exactly once.

`JobStore` reaches the records and the live state only through its ports (`ports`): production
builds it on an Engine and a Redis client (`JobStore(store, redis, database)`), the domain tests
on in-memory fakes (`JobStore.over`).

Tables (`records.tables`): ``jobs`` (a queued row without `dispatched_at` is a job waiting in its
tenant's queue, `jobs.queue`, so storing a job *is* queueing it), ``batches`` and ``batch_jobs``
(`jobs.batches`), ``idempotency_keys`` (tenant, endpoint, key -> job or batch id and the sha256
of the request body, inserted in the job's own transaction). The bucket keeps what is large:
``jobs/<id>/stages/`` and ``jobs/<id>/result/``, written by the pipeline.
"""

from __future__ import annotations

import builtins
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import date
from pathlib import Path
from typing import Any

import redis
from sqlalchemy import Engine

from bayesian_fields_core.job.store import LocalStore, Store
from bayesian_fields_service.jobs import usage
from bayesian_fields_service.jobs.batches import BatchRecord, batch_of_row
from bayesian_fields_service.jobs.model import (
    ACTIVE_STATES,
    BATCHES_ENDPOINT,
    CANCELLED_COLUMNS,
    JOBS_ENDPOINT,
    CancelledJob,
    JobRecord,
    JobState,
    ends,
    overall_progress,
    record_of,
    row_of,
    settle,
    utcnow,
)
from bayesian_fields_service.jobs.ports import (
    JobRecords,
    JobTx,
    LiveJobs,
    PgJobRecords,
    RedisLiveJobs,
)
from bayesian_fields_service.jobs.queue import JobQueue, admit
from bayesian_fields_service.live.redis_text import text
from bayesian_fields_service.records import fleet_metrics
from bayesian_fields_service.records.fleet_metrics import FleetRows
from bayesian_fields_service.records.ids import SCENE_ID, is_id
from bayesian_fields_service.records.leases import CONTROL_LEADER, Fence
from bayesian_fields_service.storage.stores import tenant_store
from bayesian_fields_service.webhooks.callbacks import batch_event, job_event

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class NewJobs:
    """What one submission stores in one unit of work (`JobStore.create_many`).

    `digests` (job id -> sha256 of what was asked, `model.job_digest`) and `batch_digest` are kept
    with the Idempotency-Key rows so a reuse of a key with another body is refused. With `batch`,
    its row, its links (`batch_job_ids`, default the new jobs) and its key row go in too; with
    `retry_in`, the jobs take the places of the failed jobs they retry in that batch (and their
    keys point at them). `scene_ids` are share-locked first and must be ready; with
    `admit_limit`, the tenant's unfinished jobs are counted next under its admission lock."""

    digests: dict[str, str] = field(default_factory=dict)
    batch: BatchRecord | None = None
    batch_job_ids: builtins.list[str] | None = None
    batch_digest: str = ""
    retry_in: str | None = None
    admit_limit: int | None = None
    scene_ids: Sequence[str] = ()


class JobStore:
    """Reads and writes job records over the records port and the live port (module docstring).

    `store` is the bucket (job artifacts live under each tenant's ``jobs/<id>/``)."""

    def __init__(self, store: Store, redis_client: redis.Redis, database: Engine) -> None:
        self.store = store
        self.records: JobRecords = PgJobRecords(database)
        self.live: LiveJobs = RedisLiveJobs(redis_client)
        self._redis: redis.Redis | None = redis_client
        self._database: Engine | None = database

    @classmethod
    def over(cls, store: Store, records: JobRecords, live: LiveJobs) -> JobStore:
        """A store on other ports (the in-memory fakes of the domain tests)."""
        self = cls.__new__(cls)
        self.store, self.records, self.live = store, records, live
        self._redis = self._database = None
        return self

    @property
    def database(self) -> Engine:
        """The records engine (production only: what still reaches the records outside this store,
        the queue and the heartbeats, takes it)."""
        if self._database is None:
            raise RuntimeError("this JobStore runs on a records port without an engine")
        return self._database

    @property
    def redis(self) -> redis.Redis:
        """The Redis client behind the live port (production only)."""
        if self._redis is None:
            raise RuntimeError("this JobStore runs on a live port without Redis")
        return self._redis

    @property
    def queue(self) -> JobQueue:
        return JobQueue(self.database)

    def tenant(self, tenant: str) -> Store:
        return tenant_store(self.store, tenant)

    def local_file(self, tenant: str, key: str) -> Path | None:
        """The file of the tenant's `key` (relative to its part of the bucket, already validated)
        where the bucket is a local folder, else None: a backend that cannot presign serves its
        results through the API (`GET /v1/jobs/{id}/artifacts/...`), one that can never does."""
        if not isinstance(self.store, LocalStore):
            return None
        return self.store.root / tenant_store(self.store, tenant).prefix / key

    def tenant_usage(self, tenant: str, start: date, end: date) -> dict[str, Any]:
        """The tenant's usage per day in [start, end] (UTC, inclusive) and over the period, from
        the usage ledger (`usage.tenant_usage`: one aggregate statement)."""
        return usage.tenant_usage(self.database, tenant, start, end)

    # ---- rows ----------------------------------------------------------------------------------
    def load(self, tenant: str, job_id: str) -> JobRecord | None:
        """The stored record (no live overlay), or None."""
        with self.records.read() as tx:
            row = tx.load_job(tenant, job_id)
        return record_of(row) if row is not None else None

    @staticmethod
    def _locked(tx: JobTx, tenant: str, job_id: str) -> JobRecord | None:
        row = tx.load_job(tenant, job_id, lock=True)
        return record_of(row) if row is not None else None

    def create(self, record: JobRecord, *, admit_limit: int | None = None) -> None:
        """Persist a new job with its Idempotency-Key row in one transaction: committed, it waits
        in its tenant's queue (`jobs.queue`)."""
        self.create_many([record], NewJobs(admit_limit=admit_limit))

    def create_many(self, records: builtins.list[JobRecord], new: NewJobs | None = None) -> int | None:
        """`create` for many jobs in one unit of work, with what `new` adds (`NewJobs`): the scenes
        are share-locked first and must be ready (`scenes.lock_ready`: `SceneGone`,
        `SceneNotReady`), so a scene's delete waits for these jobs and then sees them; then the
        admission count (`queue.admit`: `AdmissionRefused`), the batch row, the jobs, their key
        rows, the batch's links and key row.

        Committed, the jobs wait in their tenant's queue. Nothing goes to the live state: a job
        gets its live hash when the dispatcher sends it (`touch_live`), so a submission needs no
        Redis at all and a cancel of waiting jobs has no hash to update.

        Returns the tenant's unfinished jobs with these (as admitted, under the admission lock)
        where `admit_limit` is given, else None."""
        new = new or NewJobs()
        batch = new.batch
        unfinished = None
        with self.records.write() as tx:
            if records and new.scene_ids:
                tx.lock_ready_scenes(records[0].tenant, new.scene_ids)
            if records and new.admit_limit is not None:
                unfinished = admit(tx, records[0].tenant, len(records), new.admit_limit) + len(records)
            if batch is not None:
                tx.insert_batch(id=batch.id, tenant=batch.tenant, priority=batch.priority,
                                callback_url=batch.callback_url, job_count=len(new.batch_job_ids or records),
                                idempotency_key=batch.idempotency_key)  # fmt: skip
            if records:
                tx.insert_jobs([row_of(r) for r in records])
            keyed = [  # with the jobs: a retry after a crash finds them
                {"tenant": r.tenant, "endpoint": JOBS_ENDPOINT, "key": r.idempotency_key,
                 "body_sha256": new.digests.get(r.id, ""), "target_id": r.id}
                for r in records if r.idempotency_key
            ]  # fmt: skip
            tx.remember_keys(keyed, replace=new.retry_in is not None)
            if batch is not None:
                tx.insert_links(batch.id, new.batch_job_ids or [r.id for r in records])
                if batch.idempotency_key:
                    tx.remember_keys([{"tenant": batch.tenant, "endpoint": BATCHES_ENDPOINT,
                                       "key": batch.idempotency_key, "body_sha256": new.batch_digest,
                                       "target_id": batch.id}])  # fmt: skip
            if new.retry_in is not None:
                tx.replace_batch_jobs(new.retry_in, {r.retry_of: r.id for r in records if r.retry_of})
        return unfinished

    def save(self, record: JobRecord, *, answers: Sequence[dict[str, Any]] = ()) -> JobRecord:
        """Write `record`, settled over the stored row (`model.settle`) under the row's lock so the
        API's cancel and a worker's stage update never lose each other's fields.

        A job whose cancel was accepted never becomes *succeeded*: a success written after (or
        racing with) an accepted cancel is stored as *cancelled* (`request_cancel` sets the flag
        under the same row lock, so the two are ordered). The caller removes the result
        (`pipeline.discard_result`) when the saved state is cancelled.

        `answers` (the rows of `jobs.answers`, read from the result before this transaction) are
        written in the transaction that makes the job succeeded, replacing any it had: a success
        and its answers commit together or not at all (issue 42)."""
        with self.records.write() as tx:
            old = self._locked(tx, record.tenant, record.id)
            merged = self._settle_and_write(tx, old, record)
            if ends(old, merged):
                if merged.state == JobState.succeeded:
                    tx.replace_answers(merged.id, answers)
                self._queue_ends(tx, [merged])
        return self._after_write(merged)

    def _settle_and_write(self, tx: JobTx, old: JobRecord | None, record: JobRecord) -> JobRecord:
        merged = settle(old, record)
        if (
            merged.state == JobState.succeeded
            and ends(old, merged)
            and self.is_cancel_requested(record.tenant, record.id)
        ):  # the live flag of a cancel accepted since the worker read its row: cancel wins
            merged = settle(old, record, cancel_flagged=True)
        if old is None:
            tx.insert_job(row_of(merged))
        else:
            tx.write_job(row_of(merged))
        return merged

    @staticmethod
    def _queue_ends(tx: JobTx, ended: Sequence[JobRecord | CancelledJob]) -> None:
        """In the unit of work that ended `ended`: their callback events and those of the batches
        that finished with them, rows of the outbox (`webhooks.callbacks`), and their usage
        ledger end rows (`usage.end_rows`), committed with the change or not at all: every end
        counts once, a job cancelled while waiting included."""
        for record in ended:
            if (event := job_event(record)) is not None:
                tx.enqueue_event(*event)
        if ended:
            tx.insert_usage_ends(usage.end_rows(ended))
        for row in tx.mark_batches_finished([r.id for r in ended]) if ended else []:
            if (event := batch_event(batch_of_row(row))) is not None:
                tx.enqueue_event(*event)

    def _after_write(self, merged: JobRecord) -> JobRecord:
        try:
            self.touch_live(merged)
        except redis.RedisError as exc:  # display only: the row is written
            log.warning("live state of %s/%s not updated (Redis: %s)", merged.tenant, merged.id, exc)
        return merged

    def touch_live(self, record: JobRecord) -> None:
        """Mirror the record's state into its live hash (the 'job is known to Redis' mark).

        ``phase`` is 'waiting' (a message is queued for the next stage) or 'active' (a worker is
        executing a stage and holds its lock, see `set_progress`); recovery treats 'active'
        without a lock as a crashed worker."""
        self.live.touch(record.tenant, record.id, record.state.value, record.stage or "", record.progress,
                        terminal=record.state.terminal)  # fmt: skip

    def set_progress(self, record: JobRecord, stage: str, fraction: float) -> None:
        """Live progress of a running stage (the live port only; cheap enough to call per frame)."""
        self.live.set_progress(
            record.tenant, record.id, stage, overall_progress(record.stages_done, stage, fraction)
        )

    def live_phase(self, tenant: str, job_id: str) -> str | None:
        """'waiting' / 'active' from the live hash; None when Redis does not know the job."""
        return self.live.phase(tenant, job_id)

    def has_live_entry(self, tenant: str, job_id: str) -> bool:
        return self.live.has_entry(tenant, job_id)

    def get(self, tenant: str, job_id: str) -> JobRecord | None:
        """The record with the live stage/progress overlaid while the job is active."""
        record = self.load(tenant, job_id)
        return self._with_live(record) if record is not None else None

    def get_many(self, tenant: str, job_ids: builtins.list[str]) -> dict[str, JobRecord]:
        """Records of `job_ids` (those that exist), live overlay included: one query and one
        Redis round trip however many ids."""
        if not job_ids:
            return {}
        with self.records.read() as tx:
            rows = tx.load_jobs(tenant, job_ids)
        found = [record_of(r) for r in rows]
        return {r.id: r for r in self._with_live_many(found)}

    def _with_live(self, record: JobRecord) -> JobRecord:
        return self._with_live_many([record])[0]

    def _with_live_many(self, records: builtins.list[JobRecord]) -> builtins.list[JobRecord]:
        active = [r for r in records if not r.state.terminal]
        if not active:
            return records
        try:
            found = self.live.overlays([(r.tenant, r.id) for r in active])
        except redis.RedisError:  # Redis is only progress display: the rows answer without it
            return records
        overlays = dict(zip((r.id for r in active), found, strict=True))
        return [_overlaid(r, overlays[r.id]) if r.id in overlays else r for r in records]

    # ---- cancellation --------------------------------------------------------------------------
    def request_cancel(self, tenant: str, job_id: str) -> JobRecord | None:
        """Flag the job for cancellation; a job no worker has started is cancelled at once.

        Under the row lock: a job that is already terminal is returned unchanged (the cancel is
        not accepted: ``cancel_requested`` stays false), and a cancel that is accepted is seen by
        the worker's final save, which then stores *cancelled* instead of *succeeded*."""
        with self.records.write() as tx:
            record = self._locked(tx, tenant, job_id)
            if record is None or record.state.terminal:
                return record
            update_: dict[str, Any] = {"cancel_requested": True}
            if record.state == JobState.queued:
                update_.update(state=JobState.cancelled, finished_at=utcnow(), error="cancelled by request")
            merged = self._settle_and_write(tx, record, record.model_copy(update=update_))
            if ends(record, merged):
                self._queue_ends(tx, [merged])
        self._flag_cancelled([(merged.tenant, merged.id)])
        return self._after_write(merged)

    def _flag_cancelled(self, pairs: builtins.list[tuple[str, str]]) -> None:
        """Tell running workers between frames (the live cancel flag); best effort, since the row's
        `cancel_requested` is the truth: without the flag a running job ends as cancelled at its
        next save instead of at its next frame."""
        try:
            self.live.flag_cancelled(pairs)
        except redis.RedisError as exc:
            log.warning("cancel flags of %d jobs not set (Redis: %s); their rows say so", len(pairs), exc)

    def cancel_batch(self, tenant: str, batch_id: str) -> builtins.list[CancelledJob]:
        """`request_cancel` for every active job of a batch: one UPDATE (`records.batches.
        cancel_jobs`) returning only what the callbacks and the usage ledger read, then the live
        side: a cancel flag for each job a worker runs (a few: the tenant's dispatch bound), and
        the live hashes of the jobs cancelled at once removed in one command (only dispatched jobs
        have one). Returns what changed."""
        with self.records.write() as tx:
            rows = tx.cancel_batch_jobs(tenant, batch_id, CANCELLED_COLUMNS)
            changed = [CancelledJob.of(r) for r in rows]
            ended = [c for c in changed if c.state.terminal]
            self._queue_ends(tx, ended)
        try:
            self.live.flag_cancelled([(c.tenant, c.id) for c in changed if not c.state.terminal])
            self.live.forget([(c.tenant, c.id) for c in ended])
        except redis.RedisError as exc:  # the rows are the truth: running jobs end at their next save
            log.warning("cancel flags / live state of %d jobs not updated (Redis: %s)", len(changed), exc)
        return changed

    def is_cancel_requested(self, tenant: str, job_id: str) -> bool:
        """Cheap check for workers between frames (a Redis GET)."""
        return self.live.is_cancel_flagged(tenant, job_id)

    # ---- listing -------------------------------------------------------------------------------
    def list(
        self,
        tenant: str,
        *,
        state: JobState | None = None,
        scene_id: str | None = None,
        batch_id: str | None = None,
        limit: int = 50,
        cursor: str | None = None,
    ) -> tuple[builtins.list[JobRecord], str | None]:
        """A page of jobs, newest first; `cursor` is the last id of the previous page.

        Keyset over the (tenant, id) order of the rows (ids begin with their creation time). The
        live overlay can move a queued row to running, so a running filter reads queued rows too
        and keeps those Redis says run; every other filter is the row's own."""
        if scene_id is not None and not is_id(scene_id, SCENE_ID):
            return [], None  # not an id the service issues: no scene, no jobs
        states: tuple[str, ...] | None = None
        if state == JobState.running:
            states = ACTIVE_STATES
        elif state is not None:
            states = (state.value,)
        out: builtins.list[JobRecord] = []
        position = cursor
        chunk = limit + 1
        while True:
            with self.records.read() as tx:
                rows = tx.page_jobs(tenant, states=states, scene_id=scene_id, batch_id=batch_id,
                                    before=position, limit=chunk)  # fmt: skip
            found = self._with_live_many([record_of(r) for r in rows])
            for n, record in enumerate(found):
                if state is not None and record.state != state:
                    continue
                out.append(record)
                if len(out) == limit:
                    more = n + 1 < len(found) or len(rows) == chunk
                    return out, (record.id if more else None)
            if len(rows) < chunk:
                return out, None
            position = found[-1].id

    def dispatch_next(self, tenant: str, fence: Fence | None = None) -> JobRecord | None:
        """Stamp the tenant's next waiting job dispatched (`JobQueue.take`, fenced by the leader's
        lease when given) and return its record."""
        row = self.queue.take(tenant, fence)
        return record_of(row) if row is not None else None

    def count_active(self, tenant: str | None = None) -> int:
        """Queued or running jobs (of one tenant, or of all)."""
        with self.records.read() as tx:
            return tx.count_active(tenant)

    def fleet_rows(self, stage_lease_s: float) -> FleetRows:
        """Active jobs by state, the callback outbox, the leader's lease and the stalled jobs, as
        `/metrics` reports them (`records.fleet_metrics`); raises what reaching the database raised."""
        return fleet_metrics.read(self.database, lease_name=CONTROL_LEADER, stage_lease_s=stage_lease_s)

    def active_jobs(self) -> builtins.list[tuple[str, str]]:
        """(tenant, job id) of every job whose row says queued or running."""
        with self.records.read() as tx:
            return tx.active_pairs()

    # ---- idempotency ---------------------------------------------------------------------------
    def _idempotent(self, tenant: str, endpoint: str, key: str) -> tuple[str, str] | None:
        """(target id, sha256 of the body it was first sent with) of an Idempotency-Key."""
        with self.records.read() as tx:
            return tx.lookup_key(tenant, endpoint, key)

    def idempotent_job(self, tenant: str, key: str) -> tuple[str, str] | None:
        return self._idempotent(tenant, JOBS_ENDPOINT, key)

    def idempotent_jobs(self, tenant: str, wanted: builtins.list[str]) -> dict[str, tuple[str, str]]:
        """`idempotent_job` for many keys in one query: key -> (job id, digest)."""
        if not wanted:
            return {}
        with self.records.read() as tx:
            return tx.lookup_keys(tenant, JOBS_ENDPOINT, wanted)

    def idempotent_batch(self, tenant: str, key: str) -> tuple[str, str] | None:
        return self._idempotent(tenant, BATCHES_ENDPOINT, key)

    def forget_idempotent_batch(self, tenant: str, key: str, batch_id: str) -> None:
        """Drop a batch's Idempotency-Key row (its submission failed: a retry makes a new batch)."""
        with self.records.write() as tx:
            tx.forget_key(tenant, BATCHES_ENDPOINT, key, batch_id)

    # ---- batches -------------------------------------------------------------------------------
    def load_batch(self, tenant: str, batch_id: str) -> BatchRecord | None:
        """The batch's row: its counts as the records hold them (`live_batch` adds live progress)."""
        with self.records.read() as tx:
            row = tx.load_batch(tenant, batch_id)
        return batch_of_row(row) if row is not None else None

    def live_batch(self, batch: BatchRecord) -> BatchRecord:
        """`batch` with its dispatched jobs' live state and progress: only the tenant's dispatched
        jobs (at most its dispatch bound) can differ from their rows, so this reads a few rows
        and hashes whatever the batch's size."""
        if batch.finished:
            return batch
        with self.records.read() as tx:
            dispatched = tx.dispatched_ids(batch.tenant)
            if not dispatched:
                return batch
            rows = tx.batch_job_rows(batch.id, states=ACTIVE_STATES, job_ids=dispatched)
        stored = [record_of(r) for _, r in rows]
        counts = dict(batch.counts)
        progress = batch.active_progress
        for old, live in zip(stored, self._with_live_many(stored), strict=True):
            counts[old.state.value] -= 1
            counts[live.state.value] = counts.get(live.state.value, 0) + 1
            progress += (live.progress if not live.state.terminal else 0.0) - old.progress
        return batch.model_copy(update={"counts": counts, "active_progress": progress})

    def batch_jobs(
        self,
        batch: BatchRecord,
        *,
        start: int = 0,
        limit: int | None = None,
        states: Sequence[str] | None = None,
    ) -> builtins.list[tuple[int, JobRecord]]:
        """(position, record) of the batch's jobs in submission order, live overlay included."""
        with self.records.read() as tx:
            rows = tx.batch_job_rows(batch.id, start=start, limit=limit, states=states)
        records = self._with_live_many([record_of(r) for _, r in rows])
        return [(p, rec) for (p, _), rec in zip(rows, records, strict=True)]


def _overlaid(record: JobRecord, live: dict[bytes, bytes]) -> JobRecord:
    """`record` with a live hash's stage and progress (an empty hash changes nothing)."""
    if not live:
        return record
    state = JobState(text(live.get(b"state", record.state.value.encode())))
    update_: dict[str, Any] = {"progress": max(record.progress, float(live.get(b"progress", 0)))}
    if not state.terminal:
        update_["state"] = state
    if live.get(b"stage"):
        update_["stage"] = text(live[b"stage"])
    return record.model_copy(update=update_)
