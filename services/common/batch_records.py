"""Batch records: the batch model (`BatchRecord`, its counts and whether it finished) over the
statements of `records.batches`, in the caller's transaction.

Why statements: a batch of 50,000 jobs is submitted with one multi-row INSERT of its jobs and one
of its links, its status is its own row (the triggers of migration 0003, `records.triggers`, keep
the counts in the transaction of every job change), a page is an index range over (batch,
position), cancel is one UPDATE, and the batch's end is decided by the database
(`finished_batches`) in the transaction of the change that ends it, so no Redis key, manifest or
loop over jobs stands between a request and its answer.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any

from pydantic import BaseModel, Field
from sqlalchemy import Connection

from bayesian_fields_service.common.job_queue import Priority
from bayesian_fields_service.records import batches, keys
from bayesian_fields_service.records.tables import JOB_STATES

ACTIVE_STATES = ("queued", "running")


class BatchRecord(BaseModel):
    """A group of jobs submitted together (a `batches` row with its counts)."""

    id: str
    tenant: str
    total: int = Field(0, description="Jobs in the batch (a retried job counts once, as its retry).")
    counts: dict[str, int] = Field(default_factory=dict, description="Jobs per state (row states).")
    active_progress: float = Field(0.0, description="Summed progress (percent) of the active jobs.")
    created_at: datetime | None = None
    finished_at: datetime | None = None
    priority: Priority = "bulk"
    idempotency_key: str | None = None
    callback_url: str | None = None

    @property
    def finished(self) -> bool:
        return not any(self.counts.get(s, 0) for s in ACTIVE_STATES)


def batch_of_row(row: Any) -> BatchRecord:
    return BatchRecord(
        id=row["id"], tenant=row["tenant"], total=row["job_count"],
        counts={s: int(row[s]) for s in JOB_STATES}, active_progress=float(row["active_progress"]),
        created_at=row["created_at"], finished_at=row["finished_at"], priority=row["priority"],
        idempotency_key=row["idempotency_key"], callback_url=row["callback_url"],
    )  # fmt: skip


def insert_batch(conn: Connection, batch: BatchRecord, job_count: int) -> None:
    """The batch's row, in `conn`'s transaction (before its new jobs, which name it)."""
    batches.insert_row(
        conn, id=batch.id, tenant=batch.tenant, priority=batch.priority, callback_url=batch.callback_url,
        job_count=job_count, idempotency_key=batch.idempotency_key,
    )  # fmt: skip


def insert_links(conn: Connection, batch_id: str, job_ids: Sequence[str]) -> None:
    """The batch's jobs in submission order, in `conn`'s transaction (`records.batches`)."""
    batches.insert_links(conn, batch_id, job_ids)


def load_batch(conn: Connection, tenant: str, batch_id: str) -> BatchRecord | None:
    row = batches.load(conn, tenant, batch_id)
    return batch_of_row(row) if row is not None else None


#: (position, jobs row) of a batch's jobs in submission order (`records.batches.job_rows`).
batch_job_rows = batches.job_rows

#: Accept a cancel for every active job of a batch (`records.batches.cancel_jobs`).
cancel_jobs = batches.cancel_jobs

#: A retry's new jobs take their old jobs' slots; the batch is open again.
replace_jobs = batches.replace_jobs


def finished_batches(conn: Connection, job_ids: Sequence[str]) -> list[BatchRecord]:
    """The batches holding any of `job_ids` that have no active job left and were not yet marked
    finished: marked now, in `conn`'s transaction, after the jobs' UPDATE, exactly once per finish
    (`records.batches.mark_finished`)."""
    return [batch_of_row(r) for r in batches.mark_finished(conn, job_ids)]


def remember_key(conn: Connection, tenant: str, endpoint: str, key: str, body_sha256: str,
                 target_id: str, *, replace: bool = False) -> None:  # fmt: skip
    """One Idempotency-Key row (`records.keys.remember`)."""
    keys.remember(conn, [{"tenant": tenant, "endpoint": endpoint, "key": key, "body_sha256": body_sha256,
                          "target_id": target_id}], replace=replace)  # fmt: skip
