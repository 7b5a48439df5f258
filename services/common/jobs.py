"""Job records: a row of the `jobs` table is the truth, Redis holds only live progress.

Why two places: the records database survives everything (a Redis restart, a redeploy), so a
job is never lost, while stage/progress updates arrive many times a second and belong in Redis.
A read merges the two: the row gives the record, the Redis hash overlays the live stage and
progress while the job is active. Terminal states are sticky: every write reads the row under
``SELECT ... FOR UPDATE`` and merges (`_merge`), so once a row says succeeded/failed/cancelled no
later write (a late worker, a duplicate delivery) turns it back into an active one, and the API's
cancel and a worker's stage update, serialised by the row lock, never lose each other's fields.

Tables (`records.tables`): ``jobs`` (one row per job; a queued row without `dispatched_at` is a
job waiting in its tenant's queue, `common.job_queue`, so storing a job *is* queueing it),
``batches`` and ``batch_jobs`` (a batch's
counts and its jobs in submission order; `batch_records`), ``idempotency_keys`` (tenant,
endpoint, key -> job or batch id and the sha256 of the request body, inserted in the job's own
transaction). The bucket keeps what is large: ``jobs/<id>/stages/`` and ``jobs/<id>/result/``,
written by the pipeline (job_prefix = ``jobs/<id>/``); no manifest, index marker or idempotency
object is written there any more.

Redis holds nothing a job needs to run: losing it loses progress bars and queued stage messages,
which the control process's recovery sends again from the rows.
"""

from __future__ import annotations

import builtins
import hashlib
import json
import logging
import re
import secrets
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from enum import StrEnum
from typing import Any

import redis
from pydantic import BaseModel, Field, computed_field, model_validator
from sqlalchemy import Connection, Engine

from bayesian_fields_core.job.stage_table import STAGE_TABLE, STAGES
from bayesian_fields_core.job.store import Store
from bayesian_fields_service import records as db  # `records` names lists of job records here
from bayesian_fields_service.common import batch_records, usage
from bayesian_fields_service.common.batch_records import BatchRecord
from bayesian_fields_service.common.job_queue import JobQueue, Priority, admit
from bayesian_fields_service.common.usage import JobUsage
from bayesian_fields_service.live import redis_keys
from bayesian_fields_service.live.redis_text import text
from bayesian_fields_service.records import answers as answer_records
from bayesian_fields_service.records import jobs as job_rows
from bayesian_fields_service.records import keys
from bayesian_fields_service.records.leases import Fence
from bayesian_fields_service.sanitize.text import redact_locations, scrub
from bayesian_fields_service.scenes.postgres import lock_ready
from bayesian_fields_service.storage.stores import tenant_store
from bayesian_fields_service.webhooks.callbacks import on_batch_finished, on_job_terminal

log = logging.getLogger(__name__)

#: Relative cost of each stage (in `STAGES` order, which the library defines), used to turn
#: (stage, fraction) into one overall percentage.
STAGE_WEIGHTS: dict[str, float] = {spec.name: spec.weight for spec in STAGE_TABLE}

#: Seconds a finished job's live Redis hash is kept (the manifest stays for good).
FINISHED_HASH_TTL_S = 24 * 3600


class JobState(StrEnum):
    queued = "queued"
    running = "running"
    succeeded = "succeeded"
    failed = "failed"
    cancelled = "cancelled"

    @property
    def terminal(self) -> bool:
        return self in (JobState.succeeded, JobState.failed, JobState.cancelled)


def job_digest(
    scene_id: str | None, tasks: builtins.list[str], parameters: dict[str, Any], model_profile: str
) -> str:
    """sha256 of what a job asks for, as its Idempotency-Key row keeps it: the same key sent again
    with another scene, task list, parameters or model profile is a different request (422).

    A batch item's key is digested without its scene (`scene_id` None): the client derives an
    item's key from the scene *folder* it names, and a re-run manifest uploads that folder again
    under a new scene id, which is still the same work."""
    data = {"scene_id": scene_id, "tasks": tasks, "parameters": parameters, "model_profile": model_profile}
    return hashlib.sha256(json.dumps(data, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def utcnow() -> datetime:
    return datetime.now(UTC)


def new_id(prefix: str) -> str:
    """A time-ordered id (ms timestamp in hex, then randomness): listing sorts by creation."""
    return f"{prefix}{int(time.time() * 1000):012x}{secrets.token_hex(5)}"


#: What follows an id's prefix ("s_", "j_", "b_"): the 22 lower-case hex digits `new_id` writes.
ID_DIGITS = "[0-9a-f]{22}"


def id_pattern(prefix: str) -> str:
    """The anchored pattern of the ids `new_id(prefix)` makes, for a FastAPI `Query(pattern=...)`
    (pydantic's regex engine: ``$`` is the end of the text, not before a final newline)."""
    return f"^{re.escape(prefix)}{ID_DIGITS}$"


def is_id(ident: str, prefix: str) -> bool:
    """Whether `ident` is an id `new_id(prefix)` could have made: the one check every id meets
    before it reaches the records (a NUL, a stray byte or a huge value never does)."""
    return re.fullmatch(re.escape(prefix) + ID_DIGITS, ident) is not None


def id_age_s(ident: str) -> float:
    """Seconds since `new_id` made `ident` (0 for an id not in that form)."""
    try:
        return max(0.0, time.time() - int(ident[2:14], 16) / 1000)
    except ValueError:
        return 0.0


class JobRecord(BaseModel):
    """One job as stored in its `jobs` row (and returned by the API)."""

    id: str = Field(examples=["j_0192f3a1b2c3d4e5f6a7b8"])
    tenant: str = Field(examples=["acme"])
    scene_id: str = Field(examples=["s_0192f3a1b2c3aa55bb66cc"])
    tasks: list[str] = Field(examples=[["get dish soap", "move hats and gloves"]])
    parameters: dict[str, Any] = Field(default_factory=dict, examples=[{"max_frames": 40}])
    model_profile: str = Field("default", examples=["default"])
    state: JobState = JobState.queued
    stage: str | None = Field(None, description="Stage running now (or the last one that ran).")
    progress: float = Field(0.0, ge=0, le=100, description="Overall progress in percent.")
    stages_done: list[str] = Field(default_factory=list)
    timings: dict[str, float] = Field(default_factory=dict, description="Seconds per finished stage.")
    stage_reports: dict[str, dict[str, Any]] = Field(default_factory=dict)
    error: str | None = None
    cancel_requested: bool = False
    stage_runs: int = Field(
        0,
        description="Stage executions started for this job: 3 on a clean run (one per stage); more "
        "when a stage ran again (a transient-error retry, a redelivery, a crashed worker's stage). "
        "Not a retry count.",
    )
    created_at: datetime = Field(default_factory=utcnow)
    updated_at: datetime = Field(default_factory=utcnow)
    started_at: datetime | None = None
    finished_at: datetime | None = None
    idempotency_key: str | None = None
    batch_id: str | None = Field(None, description="The batch that created this job.")
    retry_of: str | None = Field(None, description="The failed job this one retried (batch retry).")
    priority: Priority = Field(
        "interactive",
        description="Fair-share class: within a tenant's queue 'interactive' jobs go ahead of 'bulk' "
        "ones (single jobs default to interactive, batch items to bulk).",
    )
    queue_position: int | None = Field(
        None,
        description="While the job waits in its tenant's queue: 1 for the tenant's next job to be "
        "dispatched (interactive jobs first, then bulk, each oldest first); null otherwise.",
    )
    estimated_start: datetime | None = Field(
        None,
        description="While waiting: an estimate of when a worker starts it, from the tenant's recent "
        "dispatch rate (or the mean job duration); null when unknown or not waiting.",
    )
    callback_url: str | None = Field(None, description="Receives a signed POST on the terminal state.")
    usage: JobUsage = Field(default_factory=JobUsage, description="CPU / GPU seconds by stage, bytes stored.")

    @model_validator(mode="before")
    @classmethod
    def _stage_runs_from_attempts(cls, data: Any) -> Any:
        """Manifests written before the rename carry the count as `attempts`."""
        if isinstance(data, dict) and "stage_runs" not in data and "attempts" in data:
            data = {**data, "stage_runs": data["attempts"]}
        return data

    @computed_field(  # type: ignore[prop-decorator]
        description="Deprecated: the same number as `stage_runs` (its former name), kept for clients."
    )
    @property
    def attempts(self) -> int:
        return self.stage_runs

    @property
    def job_prefix(self) -> str:
        return f"jobs/{self.id}/"

    @property
    def scene_prefix(self) -> str:
        return f"scenes/{self.scene_id}/"

    def remaining_stages(self) -> list[str]:
        return [s for s in STAGES if s not in self.stages_done]


#: Fields of a `JobRecord` computed when it is read, never stored.
_READ_ONLY = {"queue_position", "estimated_start"}


def overall_progress(stages_done: Iterable[str], stage: str | None, fraction: float) -> float:
    """Percent complete from finished stages plus the fraction of the running one."""
    done = set(stages_done)
    pct = sum(STAGE_WEIGHTS[s] for s in STAGES if s in done)
    if stage in STAGE_WEIGHTS and stage not in done:
        pct += STAGE_WEIGHTS[stage] * min(max(fraction, 0.0), 1.0)
    return round(100.0 * min(pct, 1.0), 2)


def _merge(old: JobRecord, new: JobRecord) -> JobRecord:
    """Combine a concurrent writer's record with the stored one: terminal states and cancel
    requests win, finished stages accumulate."""
    if old.state.terminal and not new.state.terminal:
        new = new.model_copy(update={"state": old.state, "error": old.error, "finished_at": old.finished_at})
    stages = [s for s in STAGES if s in set(old.stages_done) | set(new.stages_done)]
    return new.model_copy(
        update={
            "cancel_requested": old.cancel_requested or new.cancel_requested,
            "stages_done": stages,
            "timings": {**old.timings, **new.timings},
            "stage_reports": {**old.stage_reports, **new.stage_reports},
            "usage": JobUsage.merged(old.usage, new.usage),
        }
    )


def _redacted(record: JobRecord) -> JobRecord:
    """The record with its error message free of paths and bucket keys (`redact_locations`)."""
    if not record.error:
        return record
    clean = redact_locations(record.error)
    return record if clean == record.error else record.model_copy(update={"error": clean})


#: `JobRecord` fields kept in a `jobs` column of the same name.
_COLUMNS = (
    "id", "tenant", "scene_id", "batch_id", "state", "priority", "tasks", "parameters", "model_profile",
    "stage", "progress", "stages_done", "timings", "stage_reports", "usage", "error", "cancel_requested",
    "stage_runs", "callback_url", "retry_of", "idempotency_key", "created_at", "updated_at", "started_at",
    "finished_at",
)  # fmt: skip

_ACTIVE_STATES = (JobState.queued.value, JobState.running.value)

#: Idempotency endpoints (the `idempotency_keys.endpoint` column).
JOBS_ENDPOINT = "jobs"
BATCHES_ENDPOINT = "batches"


def _row_of(record: JobRecord) -> dict[str, Any]:
    """The `jobs` columns of a record (JSON-ready values; read-only fields dropped)."""
    data = _redacted(record).model_dump(mode="json", exclude=_READ_ONLY)
    row = {name: data[name] for name in _COLUMNS}
    for name in ("created_at", "updated_at", "started_at", "finished_at"):
        row[name] = getattr(record, name)
    return row


def _record_of(row: Any) -> JobRecord:
    """A `JobRecord` from a `jobs` row mapping (scrubbed: a record stored before the edge
    refused lone surrogates must stay servable)."""
    data = {name: row[name] for name in _COLUMNS}
    return _redacted(JobRecord.model_validate(scrub(data)))


#: What a batch's cancel reads back of each job it changed.
_CANCELLED_COLUMNS = ("id", "tenant", "scene_id", "batch_id", "state", "error", "callback_url", "finished_at",
                      "usage")  # fmt: skip


@dataclass
class CancelledJob:
    """A job a batch's cancel changed: what its callback event and usage row read
    (`callbacks.TerminalJob`, `usage.EndedJob`), without the whole record."""

    id: str
    tenant: str
    scene_id: str
    batch_id: str | None
    state: JobState
    error: str | None
    callback_url: str | None
    finished_at: datetime | None
    usage: JobUsage

    @classmethod
    def of(cls, row: Any) -> CancelledJob:
        return cls(row["id"], row["tenant"], row["scene_id"], row["batch_id"], JobState(row["state"]),
                   row["error"], row["callback_url"], row["finished_at"],
                   JobUsage(bytes_stored=int((row["usage"] or {}).get("bytes_stored", 0))))  # fmt: skip


class JobStore:
    """Reads and writes job records (`jobs` rows + Redis live state + cancel flags).

    `store` is the bucket (job artifacts live under each tenant's ``jobs/<id>/``); `database` the
    records engine (`records.database.engine`)."""

    def __init__(self, store: Store, redis_client: redis.Redis, database: Engine) -> None:
        self.store = store
        self.redis = redis_client
        self.database = database
        self.queue = JobQueue(database)

    # ---- keys ----------------------------------------------------------------------------------
    @staticmethod
    def live_key(tenant: str, job_id: str) -> str:
        return redis_keys.live_job(tenant, job_id)

    @staticmethod
    def cancel_key(tenant: str, job_id: str) -> str:
        return redis_keys.cancel_flag(tenant, job_id)

    def tenant(self, tenant: str) -> Store:
        return tenant_store(self.store, tenant)

    # ---- rows ----------------------------------------------------------------------------------
    def load(self, tenant: str, job_id: str) -> JobRecord | None:
        """The stored record (no live overlay), or None."""
        with db.connect(self.database) as conn:
            row = job_rows.load(conn, tenant, job_id)
        return _record_of(row) if row is not None else None

    @staticmethod
    def _locked(conn: Connection, tenant: str, job_id: str) -> JobRecord | None:
        row = job_rows.load(conn, tenant, job_id, lock=True)
        return _record_of(row) if row is not None else None

    def create(self, record: JobRecord, *, admit_limit: int | None = None) -> None:
        """Persist a new job with its Idempotency-Key row in one transaction: committed, it waits
        in its tenant's queue (`common.job_queue`)."""
        self.create_many([record], admit_limit=admit_limit)

    def create_many(
        self,
        records: builtins.list[JobRecord],
        *,
        digests: dict[str, str] | None = None,
        batch: BatchRecord | None = None,
        batch_job_ids: builtins.list[str] | None = None,
        batch_digest: str = "",
        retry_in: str | None = None,
        admit_limit: int | None = None,
        scene_ids: Sequence[str] = (),
    ) -> None:
        """`create` for many jobs in one transaction (a batch's new jobs, with the batch's row, its
        links and its Idempotency-Key row when `batch` is given; with `retry_in`, jobs that take
        the place of the failed jobs they retry in that batch). `digests` (job id -> sha256 of what
        was asked, `job_digest`) and `batch_digest` are kept with the Idempotency-Key rows so a
        reuse of a key with another body is refused. `scene_ids` (the scenes of `records`) are
        share-locked first and must be ready (`scenes.lock_ready`: `SceneGone`, `SceneNotReady`),
        so a scene's delete waits for these jobs and then sees them. With `admit_limit`, the
        tenant's unfinished jobs are counted next under its admission lock (`job_queue.admit`:
        `AdmissionRefused`).

        Committed, the jobs wait in their tenant's queue. Nothing goes to Redis: a job gets its
        live hash when the dispatcher sends it (`touch_live`), so a submission needs no Redis at
        all and a cancel of waiting jobs has no hash to update."""
        digests = digests or {}
        with db.begin(self.database) as conn:
            if records and scene_ids:
                lock_ready(conn, records[0].tenant, scene_ids)
            if records and admit_limit is not None:
                admit(conn, records[0].tenant, len(records), admit_limit)
            if batch is not None:
                batch_records.insert_batch(conn, batch, len(batch_job_ids or records))
            if records:
                job_rows.insert_many(conn, [_row_of(r) for r in records])
            keyed = [  # with the jobs: a retry after a crash finds them
                {"tenant": r.tenant, "endpoint": JOBS_ENDPOINT, "key": r.idempotency_key,
                 "body_sha256": digests.get(r.id, ""), "target_id": r.id}
                for r in records if r.idempotency_key
            ]  # fmt: skip
            keys.remember(conn, keyed, replace=retry_in is not None)
            if batch is not None:
                batch_records.insert_links(conn, batch.id, batch_job_ids or [r.id for r in records])
                if batch.idempotency_key:
                    batch_records.remember_key(conn, batch.tenant, BATCHES_ENDPOINT, batch.idempotency_key,
                                               batch_digest, batch.id)  # fmt: skip
            if retry_in is not None:
                batch_records.replace_jobs(conn, retry_in, {r.retry_of: r.id for r in records if r.retry_of})

    def save(self, record: JobRecord, *, answers: Sequence[dict[str, Any]] = ()) -> JobRecord:
        """Write `record`, merged with the stored row (see `_merge`) under the row's lock so the
        API's cancel and a worker's stage update never lose each other's fields.

        A job whose cancel was accepted never becomes *succeeded*: a success written after (or
        racing with) an accepted cancel is stored as *cancelled* (`request_cancel` sets the flag
        under the same row lock, so the two are ordered). The caller removes the result
        (`pipeline.discard_result`) when the saved state is cancelled.

        `answers` (the rows of `jobs.answers`, read from the result before this transaction) are
        written in the transaction that makes the job succeeded, replacing any it had: a success
        and its answers commit together or not at all (issue 42)."""
        with db.begin(self.database) as conn:
            old = self._locked(conn, record.tenant, record.id)
            merged = self._merge_and_write(conn, old, record)
            if merged.state.terminal and (old is None or not old.state.terminal):
                if merged.state == JobState.succeeded:
                    answer_records.replace_job(conn, merged.id, answers)
                self._queue_callbacks(conn, [merged])
        return self._after_write(merged)

    def _merge_and_write(self, conn: Connection, old: JobRecord | None, record: JobRecord) -> JobRecord:
        merged = _merge(old, record) if old is not None else record
        if (
            merged.state == JobState.succeeded
            and (old is None or not old.state.terminal)
            and (merged.cancel_requested or self.is_cancel_requested(record.tenant, record.id))
        ):
            merged = merged.model_copy(
                update={
                    "state": JobState.cancelled,
                    "cancel_requested": True,
                    "error": "cancelled by request",
                }
            )
        merged.updated_at = utcnow()
        row = _row_of(merged)
        if old is None:
            job_rows.insert_row(conn, row)
        else:
            job_rows.write_row(conn, row)
        return merged

    @staticmethod
    def _queue_callbacks(conn: Connection, ended: Sequence[JobRecord | CancelledJob]) -> None:
        """In the transaction that ended `ended`: their callback events and those of the batches
        that finished with them (`batch_records.finished_batches`), rows of the outbox
        (`callbacks`), and their usage ledger rows (`usage.record_job_ends`), committed with the
        change or not at all: every end counts once, a job cancelled while waiting included."""
        for record in ended:
            on_job_terminal(conn, record)
        usage.record_job_ends(conn, ended)
        for batch in batch_records.finished_batches(conn, [r.id for r in ended]):
            on_batch_finished(conn, batch)

    def _after_write(self, merged: JobRecord) -> JobRecord:
        try:
            self.touch_live(merged)
        except redis.RedisError as exc:  # display only: the row is written
            log.warning("live state of %s/%s not updated (Redis: %s)", merged.tenant, merged.id, exc)
        return merged

    def touch_live(self, record: JobRecord) -> None:
        """Mirror the record's state into its live Redis hash (the 'job is known to Redis' mark).

        ``phase`` is 'waiting' (a message is queued for the next stage) or 'active' (a worker is
        executing a stage and holds its lock, see `set_progress`); recovery treats 'active'
        without a lock as a crashed worker."""
        pipe = self.redis.pipeline()
        self._queue_live(pipe, record)
        pipe.execute()

    def _queue_live(self, pipe: Any, record: JobRecord) -> None:
        key = self.live_key(record.tenant, record.id)
        pipe.hset(
            key,
            mapping={
                "state": record.state.value,
                "stage": record.stage or "",
                "progress": record.progress,
                "phase": "waiting",
                "updated": time.time(),
            },
        )
        if record.state.terminal:
            pipe.expire(key, FINISHED_HASH_TTL_S)
        else:
            pipe.persist(key)

    def set_progress(self, record: JobRecord, stage: str, fraction: float) -> None:
        """Live progress of a running stage (Redis only; cheap enough to call per frame)."""
        pct = overall_progress(record.stages_done, stage, fraction)
        self.redis.hset(
            self.live_key(record.tenant, record.id),
            mapping={
                "state": JobState.running.value,
                "stage": stage,
                "progress": pct,
                "phase": "active",
                "updated": time.time(),
            },
        )

    def live_phase(self, tenant: str, job_id: str) -> str | None:
        """'waiting' / 'active' from the live hash; None when Redis does not know the job."""
        phase = self.redis.hget(self.live_key(tenant, job_id), "phase")
        return text(phase) if phase is not None else None

    def has_live_entry(self, tenant: str, job_id: str) -> bool:
        return bool(self.redis.exists(self.live_key(tenant, job_id)))

    def get(self, tenant: str, job_id: str) -> JobRecord | None:
        """The record with the live stage/progress overlaid while the job is active."""
        record = self.load(tenant, job_id)
        return self._with_live(record) if record is not None else None

    def get_many(self, tenant: str, job_ids: builtins.list[str]) -> dict[str, JobRecord]:
        """Records of `job_ids` (those that exist), live overlay included: one query and one
        Redis round trip however many ids."""
        if not job_ids:
            return {}
        with db.connect(self.database) as conn:
            rows = job_rows.load_many(conn, tenant, job_ids)
        found = [_record_of(r) for r in rows]
        return {r.id: r for r in self._with_live_many(found)}

    def _with_live(self, record: JobRecord) -> JobRecord:
        return self._with_live_many([record])[0]

    def _with_live_many(self, records: builtins.list[JobRecord]) -> builtins.list[JobRecord]:
        active = [r for r in records if not r.state.terminal]
        if not active:
            return records
        pipe = self.redis.pipeline()
        for record in active:
            pipe.hgetall(self.live_key(record.tenant, record.id))
        try:
            overlays = dict(zip((r.id for r in active), pipe.execute(), strict=True))
        except redis.RedisError:  # Redis is only progress display: the rows answer without it
            return records
        return [_overlaid(r, overlays[r.id]) if r.id in overlays else r for r in records]

    # ---- cancellation --------------------------------------------------------------------------
    def request_cancel(self, tenant: str, job_id: str) -> JobRecord | None:
        """Flag the job for cancellation; a job no worker has started is cancelled at once.

        Under the row lock: a job that is already terminal is returned unchanged (the cancel is
        not accepted: ``cancel_requested`` stays false), and a cancel that is accepted is seen by
        the worker's final save, which then stores *cancelled* instead of *succeeded*."""
        with db.begin(self.database) as conn:
            record = self._locked(conn, tenant, job_id)
            if record is None or record.state.terminal:
                return record
            update_: dict[str, Any] = {"cancel_requested": True}
            if record.state == JobState.queued:
                update_.update(state=JobState.cancelled, finished_at=utcnow(), error="cancelled by request")
            merged = self._merge_and_write(conn, record, record.model_copy(update=update_))
            if merged.state.terminal:
                self._queue_callbacks(conn, [merged])
        self._flag_cancelled([merged])
        return self._after_write(merged)

    def _flag_cancelled(self, records: builtins.list[JobRecord]) -> None:
        """Tell running workers between frames (the Redis flag); best effort, since the row's
        `cancel_requested` is the truth: without the flag a running job ends as cancelled at its
        next save instead of at its next frame."""
        try:
            pipe = self.redis.pipeline(transaction=False)
            for record in records:
                pipe.set(self.cancel_key(record.tenant, record.id), b"1", ex=FINISHED_HASH_TTL_S * 7)
            pipe.execute()
        except redis.RedisError as exc:
            log.warning("cancel flags of %d jobs not set (Redis: %s); their rows say so", len(records), exc)

    def cancel_batch(self, tenant: str, batch_id: str) -> builtins.list[CancelledJob]:
        """`request_cancel` for every active job of a batch: one UPDATE (`batch_records.
        cancel_jobs`) returning only what the callbacks and the usage ledger read, then the Redis
        side: a cancel flag for each job a worker runs (a few: the tenant's dispatch bound), and
        the live hashes of the jobs cancelled at once removed in one command (only dispatched jobs
        have one). Returns what changed."""
        with db.begin(self.database) as conn:
            rows = batch_records.cancel_jobs(conn, tenant, batch_id, columns=_CANCELLED_COLUMNS)
            changed = [CancelledJob.of(r) for r in rows]
            ended = [c for c in changed if c.state.terminal]
            self._queue_callbacks(conn, ended)
        try:
            running = [c for c in changed if not c.state.terminal]
            pipe = self.redis.pipeline(transaction=False)
            for job in running:
                pipe.set(self.cancel_key(job.tenant, job.id), b"1", ex=FINISHED_HASH_TTL_S * 7)
            if ended:
                pipe.delete(*[self.live_key(job.tenant, job.id) for job in ended])
            pipe.execute()
        except redis.RedisError as exc:  # the rows are the truth: running jobs end at their next save
            log.warning("cancel flags / live state of %d jobs not updated (Redis: %s)", len(changed), exc)
        return changed

    def is_cancel_requested(self, tenant: str, job_id: str) -> bool:
        """Cheap check for workers between frames (a Redis GET)."""
        return bool(self.redis.exists(self.cancel_key(tenant, job_id)))

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
        if scene_id is not None and not is_id(scene_id, "s_"):
            return [], None  # not an id the service issues: no scene, no jobs
        states: tuple[str, ...] | None = None
        if state == JobState.running:
            states = _ACTIVE_STATES
        elif state is not None:
            states = (state.value,)
        out: builtins.list[JobRecord] = []
        position = cursor
        chunk = limit + 1
        while True:
            with db.connect(self.database) as conn:
                rows = job_rows.page(conn, tenant, states=states, scene_id=scene_id, batch_id=batch_id,
                                     before=position, limit=chunk)  # fmt: skip
            found = self._with_live_many([_record_of(r) for r in rows])
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
        return _record_of(row) if row is not None else None

    def count_active(self, tenant: str | None = None) -> int:
        """Queued or running jobs (of one tenant, or of all)."""
        with db.connect(self.database) as conn:
            return job_rows.count_active(conn, tenant)

    def active_jobs(self) -> builtins.list[tuple[str, str]]:
        """(tenant, job id) of every job whose row says queued or running."""
        with db.connect(self.database) as conn:
            return job_rows.active_pairs(conn)

    # ---- idempotency ---------------------------------------------------------------------------
    def _idempotent(self, tenant: str, endpoint: str, key: str) -> tuple[str, str] | None:
        """(target id, sha256 of the body it was first sent with) of an Idempotency-Key."""
        with db.connect(self.database) as conn:
            return keys.lookup(conn, tenant, endpoint, key)

    def idempotent_job(self, tenant: str, key: str) -> tuple[str, str] | None:
        return self._idempotent(tenant, JOBS_ENDPOINT, key)

    def idempotent_jobs(self, tenant: str, wanted: builtins.list[str]) -> dict[str, tuple[str, str]]:
        """`idempotent_job` for many keys in one query: key -> (job id, digest)."""
        if not wanted:
            return {}
        with db.connect(self.database) as conn:
            return keys.lookup_many(conn, tenant, JOBS_ENDPOINT, wanted)

    def idempotent_batch(self, tenant: str, key: str) -> tuple[str, str] | None:
        return self._idempotent(tenant, BATCHES_ENDPOINT, key)

    def forget_idempotent_batch(self, tenant: str, key: str, batch_id: str) -> None:
        """Drop a batch's Idempotency-Key row (its submission failed: a retry makes a new batch)."""
        with db.begin(self.database) as conn:
            keys.forget(conn, tenant, BATCHES_ENDPOINT, key, batch_id)

    # ---- batches -------------------------------------------------------------------------------
    def load_batch(self, tenant: str, batch_id: str) -> BatchRecord | None:
        """The batch's row: its counts as the records hold them (`live_batch` adds live progress)."""
        with db.connect(self.database) as conn:
            return batch_records.load_batch(conn, tenant, batch_id)

    def live_batch(self, batch: BatchRecord) -> BatchRecord:
        """`batch` with its dispatched jobs' live state and progress: only the tenant's dispatched
        jobs (at most its dispatch bound) can differ from their rows, so this reads a few rows
        and hashes whatever the batch's size."""
        if batch.finished:
            return batch
        dispatched = self.queue.dispatched_ids(batch.tenant)
        if not dispatched:
            return batch
        with db.connect(self.database) as conn:
            rows = batch_records.batch_job_rows(conn, batch.id, states=_ACTIVE_STATES, job_ids=dispatched)
        stored = [_record_of(r) for _, r in rows]
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
        with db.connect(self.database) as conn:
            rows = batch_records.batch_job_rows(conn, batch.id, start=start, limit=limit, states=states)
        records = self._with_live_many([_record_of(r) for _, r in rows])
        return [(p, rec) for (p, _), rec in zip(rows, records, strict=True)]


def _overlaid(record: JobRecord, live: dict[bytes, bytes]) -> JobRecord:
    """`record` with a live Redis hash's stage and progress (an empty hash changes nothing)."""
    if not live:
        return record
    state = JobState(text(live.get(b"state", record.state.value.encode())))
    update_: dict[str, Any] = {"progress": max(record.progress, float(live.get(b"progress", 0)))}
    if not state.terminal:
        update_["state"] = state
    if live.get(b"stage"):
        update_["stage"] = text(live[b"stage"])
    return record.model_copy(update=update_)
