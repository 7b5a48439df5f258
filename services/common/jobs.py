"""Job records: the manifest in the bucket is the truth, Redis holds only live progress.

Why two places: the bucket survives everything (a Redis restart, a redeploy), so a job is never
lost, while stage/progress updates arrive many times a second and belong in Redis. A read merges
the two: the manifest gives the record, the Redis hash overlays the live stage and progress while
the job is active. Terminal states are sticky: once a manifest says succeeded/failed/cancelled no
later write (a late worker, a duplicate delivery) turns it back into an active one.

Layout (keys of the tenant's store, i.e. under ``tenants/<tenant>/``):
  jobs/<id>/manifest.json          the `JobRecord`
  jobs/<id>/stages/, jobs/<id>/result/   written by the pipeline (job_prefix = ``jobs/<id>/``)
  index/jobs/<id>                  empty marker, so listing jobs never walks result files
  index/jobs-by-state/<state>/<id> empty marker per job in its current manifest state, and
  index/jobs-by-scene/<scene>/<id> per job of a scene: a filtered page lists these keys and reads
                                   only the manifests it returns (not every manifest until the
                                   page fills); ``index/jobs-by.json`` says they are complete
  idempotency/<sha256(key)>.json   Idempotency-Key -> job id (survives Redis restarts)
  batches/<id>.json                a `BatchRecord`
and in the global store ``active/<tenant>/<id>`` markers for queued/running jobs, which the
worker's recovery scan reads to re-enqueue jobs a Redis restart dropped, and ``pending/<tenant>/<id>``
markers for jobs stored but not yet enqueued: the API deletes it right after the enqueue, so one
that outlives the recovery grace period is a submission whose API stopped half-way (recovery
enqueues it: see `worker.recovery`; a retry with the same Idempotency-Key finds it, since
`create` stores the key with the job).

Redis also holds the per-tenant quota set (`bayesian_fields_service.common.quota`): taken before a job is
stored, given back here on every terminal state.
"""

from __future__ import annotations

import builtins
import hashlib
import logging
import re
import secrets
import time
from collections.abc import Iterable
from datetime import UTC, datetime
from enum import StrEnum
from typing import Any

import redis
from pydantic import BaseModel, Field, computed_field, model_validator

from bayesian_fields_core.job.stage_table import STAGE_TABLE, STAGES
from bayesian_fields_core.job.store import ArtifactNotFound, Store, get_json, put_json
from bayesian_fields_service.common.callbacks import on_job_terminal
from bayesian_fields_service.common.fair_queue import Priority, dispatched_key
from bayesian_fields_service.common.quota import TenantQuota
from bayesian_fields_service.common.redis_text import text
from bayesian_fields_service.common.sanitize import redact_locations, scrub
from bayesian_fields_service.common.storage import tenant_store
from bayesian_fields_service.common.usage import JobUsage

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


def utcnow() -> datetime:
    return datetime.now(UTC)


def new_id(prefix: str) -> str:
    """A time-ordered id (ms timestamp in hex, then randomness): listing sorts by creation."""
    return f"{prefix}{int(time.time() * 1000):012x}{secrets.token_hex(5)}"


def id_age_s(ident: str) -> float:
    """Seconds since `new_id` made `ident` (0 for an id not in that form)."""
    try:
        return max(0.0, time.time() - int(ident[2:14], 16) / 1000)
    except ValueError:
        return 0.0


class JobRecord(BaseModel):
    """One job as stored in ``jobs/<id>/manifest.json`` (and returned by the API)."""

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
    batch_id: str | None = None
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


class BatchRecord(BaseModel):
    """A group of jobs submitted together (``batches/<id>.json``)."""

    id: str
    tenant: str
    job_ids: list[str]
    created_at: datetime = Field(default_factory=utcnow)
    priority: Priority = "bulk"
    idempotency_key: str | None = None
    callback_url: str | None = None
    retried: dict[str, str] = Field(
        default_factory=dict, description="Failed job id -> the job that retried it (in job_ids now)."
    )


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


#: Marker: the tenant's by-state / by-scene job indexes cover every job (see `_build_filter_index`).
_INDEX_DONE = "index/jobs-by.json"


def _state_index(state: JobState, job_id: str) -> str:
    return f"index/jobs-by-state/{state.value}/{job_id}"


def _scene_index(scene_id: str, job_id: str) -> str:
    return f"index/jobs-by-scene/{scene_id}/{job_id}"


def _redacted(record: JobRecord) -> JobRecord:
    """The record with its error message free of paths and bucket keys (`redact_locations`)."""
    if not record.error:
        return record
    clean = redact_locations(record.error)
    return record if clean == record.error else record.model_copy(update={"error": clean})


class JobStore:
    """Reads and writes job records (bucket manifests + Redis live state + cancel flags)."""

    def __init__(self, store: Store, redis_client: redis.Redis) -> None:
        self.store = store
        self.redis = redis_client
        self.quota = TenantQuota(redis_client)

    # ---- keys ----------------------------------------------------------------------------------
    @staticmethod
    def manifest_key(job_id: str) -> str:
        return f"jobs/{job_id}/manifest.json"

    @staticmethod
    def live_key(tenant: str, job_id: str) -> str:
        return f"bf:job:{tenant}:{job_id}"

    @staticmethod
    def cancel_key(tenant: str, job_id: str) -> str:
        return f"bf:cancel:{tenant}:{job_id}"

    @staticmethod
    def active_key(tenant: str, job_id: str) -> str:
        return f"active/{tenant}/{job_id}"

    @staticmethod
    def pending_key(tenant: str, job_id: str) -> str:
        return f"pending/{tenant}/{job_id}"

    def tenant(self, tenant: str) -> Store:
        return tenant_store(self.store, tenant)

    # ---- manifests -----------------------------------------------------------------------------
    def load(self, tenant: str, job_id: str) -> JobRecord | None:
        """The stored manifest (no live overlay), or None."""
        try:
            data = get_json(self.tenant(tenant), self.manifest_key(job_id))
        except ArtifactNotFound:
            return None
        # scrub: a manifest stored before the edge refused lone surrogates must stay servable
        return _redacted(JobRecord.model_validate(scrub(data)))

    def _write(self, record: JobRecord) -> None:
        put_json(
            self.tenant(record.tenant),
            self.manifest_key(record.id),
            _redacted(record).model_dump(mode="json", exclude=_READ_ONLY),
        )

    def create(self, record: JobRecord) -> None:
        """Persist a new job: pending + active markers, manifest, listing index, live hash.

        The caller has taken the job's quota slot, enqueues it next and then calls
        `mark_enqueued`; if it dies in between, recovery finds the pending marker."""
        ts = self.tenant(record.tenant)
        self.store.put_bytes(self.pending_key(record.tenant, record.id), b"")
        self.store.put_bytes(self.active_key(record.tenant, record.id), b"")
        self._write(record)
        ts.put_bytes(f"index/jobs/{record.id}", b"")
        ts.put_bytes(_scene_index(record.scene_id, record.id), b"")
        ts.put_bytes(_state_index(record.state, record.id), b"")
        if record.idempotency_key:  # before the enqueue: a retry after a crash finds this job
            self.remember_idempotent(record.tenant, record.idempotency_key, record.id)
        self.touch_live(record)

    def mark_enqueued(self, record: JobRecord) -> None:
        """The job's first stage message is in the queue: it is no longer a half-done submission."""
        self.store.delete(self.pending_key(record.tenant, record.id))

    def discard_unsubmitted(self, record: JobRecord) -> None:
        """Undo `create` after a failed enqueue, as far as the backends allow (best effort: what
        an outage leaves behind carries a pending marker, so recovery fails it instead of running
        it). Never raises."""
        ts = self.tenant(record.tenant)
        steps = (
            lambda: self._write(record.model_copy(update={
                "state": JobState.failed, "finished_at": utcnow(),
                "error": "submission failed: the queue was unavailable; submit again"})),
            lambda: ts.delete(f"index/jobs/{record.id}"),
            lambda: ts.delete(_scene_index(record.scene_id, record.id)),
            lambda: ts.delete(_state_index(record.state, record.id)),
            lambda: self.store.delete(self.active_key(record.tenant, record.id)),
            lambda: self.store.delete(self.pending_key(record.tenant, record.id)),
            lambda: self.redis.delete(self.live_key(record.tenant, record.id)),
            lambda: self.quota.release(record.tenant, [record.id]),
            lambda: self._forget_idempotent(record),
        )  # fmt: skip
        for step in steps:
            try:
                step()
            except Exception:  # an outage is why we are here; recovery repairs the rest
                continue

    def release_slot(self, record: JobRecord) -> None:
        """A terminal job no longer counts against its tenant's quota (markers and Redis set)."""
        self.store.delete(self.active_key(record.tenant, record.id))
        self.store.delete(self.pending_key(record.tenant, record.id))
        self.quota.release(record.tenant, [record.id])
        self.redis.zrem(dispatched_key(record.tenant), record.id)

    def _manifest_lock(self, tenant: str, job_id: str) -> Any:
        """The short Redis lock every manifest write holds (read, merge, write)."""
        return self.redis.lock(f"bf:mlock:{tenant}:{job_id}", timeout=30, blocking_timeout=30)

    def save(self, record: JobRecord) -> JobRecord:
        """Write `record`, merged with what is stored (see `_merge`) under a short Redis lock so the
        API's cancel and a worker's stage update never lose each other's fields.

        A job whose cancel was accepted never becomes *succeeded*: a success written after (or
        racing with) an accepted cancel is stored as *cancelled* (`request_cancel` sets the flag
        under the same lock, so the two are ordered). The caller removes the result
        (`pipeline.discard_result`) when the saved state is cancelled."""
        with self._manifest_lock(record.tenant, record.id):
            merged = self._merge_and_write(record)
        return self._after_write(merged)

    def _merge_and_write(self, record: JobRecord) -> JobRecord:
        old = self.load(record.tenant, record.id)
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
        self._write(merged)
        if merged.state.terminal and (old is None or not old.state.terminal):
            self._notify_terminal(merged)
        if old is not None and old.state != merged.state:
            # new entry first: a crash in between leaves a duplicate the listing filters out
            ts = self.tenant(merged.tenant)
            ts.put_bytes(_state_index(merged.state, merged.id), b"")
            ts.delete(_state_index(old.state, merged.id))
        return merged

    def _notify_terminal(self, record: JobRecord) -> None:
        """Callbacks and batch completion (`callbacks.on_job_terminal`); never fails the write."""
        try:
            on_job_terminal(self.redis, record, self.load_batch)
        except redis.RedisError as exc:
            log.warning("job %s/%s: terminal notification not queued: %s", record.tenant, record.id, exc)

    def _after_write(self, merged: JobRecord) -> JobRecord:
        if merged.state.terminal:
            self.release_slot(merged)
        self.touch_live(merged)
        return merged

    def touch_live(self, record: JobRecord) -> None:
        """Mirror the record's state into its live Redis hash (the 'job is known to Redis' mark).

        ``phase`` is 'waiting' (a message is queued for the next stage) or 'active' (a worker is
        executing a stage and holds its lock, see `set_progress`); recovery treats 'active'
        without a lock as a crashed worker."""
        key = self.live_key(record.tenant, record.id)
        pipe = self.redis.pipeline()
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
        pipe.execute()

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
        """The manifest with the live stage/progress overlaid while the job is active."""
        record = self.load(tenant, job_id)
        if record is None or record.state.terminal:
            return record
        live = self.redis.hgetall(self.live_key(tenant, job_id))
        if live:
            state = JobState(text(live.get(b"state", record.state.value.encode())))
            update: dict[str, Any] = {"progress": max(record.progress, float(live.get(b"progress", 0)))}
            if not state.terminal:
                update["state"] = state
            if live.get(b"stage"):
                update["stage"] = text(live[b"stage"])
            record = record.model_copy(update=update)
        return record

    # ---- cancellation --------------------------------------------------------------------------
    def request_cancel(self, tenant: str, job_id: str) -> JobRecord | None:
        """Flag the job for cancellation; a job no worker has started is cancelled at once.

        Under the manifest lock: a job that is already terminal is returned unchanged (the cancel
        is not accepted: ``cancel_requested`` stays false), and a cancel that is accepted is seen
        by the worker's final save, which then stores *cancelled* instead of *succeeded*."""
        with self._manifest_lock(tenant, job_id):
            record = self.load(tenant, job_id)
            if record is None or record.state.terminal:
                return record
            self.redis.set(self.cancel_key(tenant, job_id), b"1", ex=FINISHED_HASH_TTL_S * 7)
            update: dict[str, Any] = {"cancel_requested": True}
            if record.state == JobState.queued:
                update.update(state=JobState.cancelled, finished_at=utcnow(), error="cancelled by request")
            merged = self._merge_and_write(record.model_copy(update=update))
        return self._after_write(merged)

    def is_cancel_requested(self, tenant: str, job_id: str) -> bool:
        """Cheap check for workers between frames (a Redis GET)."""
        return bool(self.redis.exists(self.cancel_key(tenant, job_id)))

    # ---- listing -------------------------------------------------------------------------------
    def list_ids(self, tenant: str) -> list[str]:
        """Job ids of a tenant, newest first."""
        prefix = "index/jobs/"
        return sorted((k[len(prefix) :] for k in self.tenant(tenant).list(prefix)), reverse=True)

    def list(
        self,
        tenant: str,
        *,
        state: JobState | None = None,
        scene_id: str | None = None,
        batch_id: str | None = None,
        limit: int = 50,
        cursor: str | None = None,
    ) -> tuple[list[JobRecord], str | None]:
        """A page of jobs, newest first; `cursor` is the last id of the previous page.

        With a state or scene filter the candidates come from the filter's index (both: their
        intersection), so the manifests read are the page's own (plus any whose live state
        moved on since the index was written: the record is always checked against the filter)."""
        out: list[JobRecord] = []
        if state is None and scene_id is None:
            candidates = self.list_ids(tenant)
        else:
            candidates = self._indexed_ids(tenant, state, scene_id)
        ids = [i for i in candidates if cursor is None or i < cursor]
        for n, job_id in enumerate(ids):
            record = self.get(tenant, job_id)
            if record is None:
                continue
            if state is not None and record.state != state:
                continue
            if scene_id is not None and record.scene_id != scene_id:
                continue
            if batch_id is not None and record.batch_id != batch_id:
                continue
            out.append(record)
            if len(out) == limit:
                return out, (job_id if n + 1 < len(ids) else None)
        return out, None

    def _indexed_ids(self, tenant: str, state: JobState | None, scene_id: str | None) -> builtins.list[str]:
        if scene_id is not None and not re.fullmatch(r"s_[0-9a-f]{22}", scene_id):
            return []  # not an id the service issues: no scene, no jobs (and no odd storage key)
        ts = self.tenant(tenant)
        if not ts.exists(_INDEX_DONE):
            self._build_filter_index(tenant)
        sets = []
        if state is not None:
            # a running job's manifest may still say queued (Redis has the live state)
            states = [JobState.queued, JobState.running] if state == JobState.running else [state]
            sets.append(
                {k.rsplit("/", 1)[1] for s in states for k in ts.list(f"index/jobs-by-state/{s.value}/")}
            )
        if scene_id is not None:
            sets.append({k.rsplit("/", 1)[1] for k in ts.list(f"index/jobs-by-scene/{scene_id}/")})
        return sorted(set.intersection(*sets), reverse=True)

    def _build_filter_index(self, tenant: str) -> None:
        """One-off backfill for jobs stored before the filter index existed (reads each once)."""
        ts = self.tenant(tenant)
        for job_id in self.list_ids(tenant):
            record = self.load(tenant, job_id)
            if record is not None:
                ts.put_bytes(_scene_index(record.scene_id, job_id), b"")
                ts.put_bytes(_state_index(record.state, job_id), b"")
        put_json(ts, _INDEX_DONE, {"version": 1, "built_at": utcnow().isoformat()})

    def active_jobs(self) -> builtins.list[tuple[str, str]]:
        """(tenant, job id) of every job whose manifest was last seen queued or running."""
        return self._markers("active/")

    def pending_jobs(self) -> builtins.list[tuple[str, str]]:
        """(tenant, job id) of every job stored but not (yet) confirmed enqueued."""
        return self._markers("pending/")

    def _markers(self, prefix: str) -> builtins.list[tuple[str, str]]:
        pairs = []
        for key in self.store.list(prefix):
            parts = key.split("/")
            if len(parts) == 3:
                pairs.append((parts[1], parts[2]))
        return pairs

    # ---- idempotency ---------------------------------------------------------------------------
    @staticmethod
    def _idem_key(key: str) -> str:
        return f"idempotency/{hashlib.sha256(key.encode()).hexdigest()}.json"

    def idempotent_job(self, tenant: str, key: str) -> str | None:
        try:
            return str(get_json(self.tenant(tenant), self._idem_key(key))["job_id"])
        except ArtifactNotFound:
            return None

    def remember_idempotent(self, tenant: str, key: str, job_id: str) -> None:
        put_json(self.tenant(tenant), self._idem_key(key), {"job_id": job_id})

    @staticmethod
    def _batch_idem_key(key: str) -> str:
        return f"idempotency/batches/{hashlib.sha256(key.encode()).hexdigest()}.json"

    def idempotent_batch(self, tenant: str, key: str) -> str | None:
        try:
            return str(get_json(self.tenant(tenant), self._batch_idem_key(key))["batch_id"])
        except ArtifactNotFound:
            return None

    def remember_idempotent_batch(self, tenant: str, key: str, batch_id: str) -> None:
        put_json(self.tenant(tenant), self._batch_idem_key(key), {"batch_id": batch_id})

    def _forget_idempotent(self, record: JobRecord) -> None:
        """Drop the key of a submission that was undone, so the client's retry makes a new job."""
        key = record.idempotency_key
        if key and self.idempotent_job(record.tenant, key) == record.id:
            self.tenant(record.tenant).delete(self._idem_key(key))

    # ---- batches -------------------------------------------------------------------------------
    def save_batch(self, batch: BatchRecord) -> None:
        put_json(self.tenant(batch.tenant), f"batches/{batch.id}.json", batch.model_dump(mode="json"))

    def load_batch(self, tenant: str, batch_id: str) -> BatchRecord | None:
        try:
            return BatchRecord.model_validate(get_json(self.tenant(tenant), f"batches/{batch_id}.json"))
        except ArtifactNotFound:
            return None
