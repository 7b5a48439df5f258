"""The job model: a job's record (`JobRecord`), its states (`JobState`), and the rules of a write
that every path obeys, as pure functions the store applies under the row lock.

Rules (`settle`): terminal states are sticky (a late worker or a duplicate delivery never turns an
ended job back), finished stages, timings, reports and usage accumulate, a cancel request is never
lost, and a job whose cancel was accepted never becomes *succeeded* (cancel wins). Pure, so the
domain tests check them without a database (`tests/services/jobs`).
"""

from __future__ import annotations

import builtins
import hashlib
import json
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import UTC, datetime
from enum import StrEnum
from typing import Any

from pydantic import BaseModel, Field, computed_field, model_validator
from pydantic.json_schema import SkipJsonSchema

from bayesian_fields_core.job.stage_table import STAGE_TABLE, STAGES
from bayesian_fields_service.jobs.queue import Priority
from bayesian_fields_service.jobs.usage import JobUsage
from bayesian_fields_service.records.tables import ACTIVE_JOB_STATES, TERMINAL_JOB_STATES
from bayesian_fields_service.sanitize.text import redact_locations, scrub

#: Relative cost of each stage (in `STAGES` order, which the library defines), used to turn
#: (stage, fraction) into one overall percentage.
STAGE_WEIGHTS: dict[str, float] = {spec.name: spec.weight for spec in STAGE_TABLE}


class JobState(StrEnum):
    """A job's states; which are terminal is `records.tables.TERMINAL_JOB_STATES` (spelled once)."""

    queued = "queued"
    running = "running"
    succeeded = "succeeded"
    failed = "failed"
    cancelled = "cancelled"

    @property
    def terminal(self) -> bool:
        return self.value in TERMINAL_JOB_STATES


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
    # The W3C traceparent of the submission's span (tracing on), so the control process's
    # dispatch and the workers' spans join the job's one trace (`observability.tracing`). Kept on
    # the row, never shown to clients: not serialised, not in the API's schema.
    traceparent: SkipJsonSchema[str | None] = Field(None, exclude=True)

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


def merge(old: JobRecord, new: JobRecord) -> JobRecord:
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


def settle(old: JobRecord | None, new: JobRecord, cancel_flagged: bool = False) -> JobRecord:
    """What a write of `new` stores over the row `old` (None: a new row): `merge`d, and a success
    that reaches a job whose cancel was accepted (the row's `cancel_requested`, or the live cancel
    flag `cancel_flagged`) stored as *cancelled* instead: cancel wins. A job already terminal
    keeps its state (`merge`), so a duplicate end changes nothing."""
    merged = merge(old, new) if old is not None else new
    if (
        merged.state == JobState.succeeded
        and (old is None or not old.state.terminal)
        and (merged.cancel_requested or cancel_flagged)
    ):
        merged = merged.model_copy(
            update={"state": JobState.cancelled, "cancel_requested": True, "error": "cancelled by request"}
        )
    return merged.model_copy(update={"updated_at": utcnow()})


def ends(old: JobRecord | None, merged: JobRecord) -> bool:
    """Whether the write from `old` to `merged` ends the job: the one write that queues its
    callback and usage rows (a duplicate end, over a row already terminal, queues nothing)."""
    return merged.state.terminal and (old is None or not old.state.terminal)


def redacted(record: JobRecord) -> JobRecord:
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
    "finished_at", "traceparent",
)  # fmt: skip

#: The states in which a job is unfinished (waiting or running).
ACTIVE_STATES = ACTIVE_JOB_STATES

#: Idempotency endpoints (the `idempotency_keys.endpoint` column).
JOBS_ENDPOINT = "jobs"
BATCHES_ENDPOINT = "batches"


def row_of(record: JobRecord) -> dict[str, Any]:
    """The `jobs` columns of a record (JSON-ready values; read-only fields dropped)."""
    data = redacted(record).model_dump(mode="json", exclude=_READ_ONLY)
    row = {name: data.get(name) for name in _COLUMNS}
    for name in ("created_at", "updated_at", "started_at", "finished_at", "traceparent"):
        row[name] = getattr(record, name)  # the times as datetimes; traceparent is not dumped
    return row


def record_of(row: Any) -> JobRecord:
    """A `JobRecord` from a `jobs` row mapping (scrubbed: a record stored before the edge
    refused lone surrogates must stay servable)."""
    data = {name: row[name] for name in _COLUMNS}
    return redacted(JobRecord.model_validate(scrub(data)))


#: What a batch's cancel reads back of each job it changed.
CANCELLED_COLUMNS = ("id", "tenant", "scene_id", "batch_id", "state", "error", "callback_url", "finished_at",
                      "usage")  # fmt: skip


@dataclass
class CancelledJob:
    """A job a batch's cancel changed: what its callback event and usage row read
    (`webhooks.callbacks.TerminalJob`, `usage.EndedJob`), without the whole record."""

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
