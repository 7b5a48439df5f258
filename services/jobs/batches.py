"""Batches: the batch model (`BatchRecord`, its counts and whether it finished) and the one rule
of a batch's status (`batch_progress`); the statements are `records.batches`, reached through the
records port (`ports.JobTx`).

Why statements: a batch of 50,000 jobs is submitted with one multi-row INSERT of its jobs and one
of its links, its status is its own row (the triggers of migration 0003, `records.triggers`, keep
the counts in the transaction of every job change), a page is an index range over (batch,
position), cancel is one UPDATE, and the batch's end is decided by the database
(`records.batches.mark_finished`) in the transaction of the change that ends it, so no Redis key, manifest or
loop over jobs stands between a request and its answer.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from pydantic import BaseModel, Field

from bayesian_fields_service.jobs.queue import Priority
from bayesian_fields_service.records.tables import ACTIVE_JOB_STATES, JOB_STATES, TERMINAL_JOB_STATES


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
        return not any(self.counts.get(s, 0) for s in ACTIVE_JOB_STATES)


def batch_of_row(row: Any) -> BatchRecord:
    return BatchRecord(
        id=row["id"], tenant=row["tenant"], total=row["job_count"],
        counts={s: int(row[s]) for s in JOB_STATES}, active_progress=float(row["active_progress"]),
        created_at=row["created_at"], finished_at=row["finished_at"], priority=row["priority"],
        idempotency_key=row["idempotency_key"], callback_url=row["callback_url"],
    )  # fmt: skip


@dataclass(frozen=True)
class BatchProgress:
    """What a batch's status says of its jobs: per-state counts (states with none left out), the
    mean progress in percent (an ended job counts 100) and whether none is active."""

    counts: dict[str, int]
    progress: float
    finished: bool


def batch_progress(counts: Mapping[str, int], active_progress: float, total: int) -> BatchProgress:
    """The batch status rule, the one place it is computed: from the jobs per state, the summed
    progress of the active ones and how many jobs the mean is over (`total`). The API's status
    from the row's counts, its status listing the jobs and its event stream all answer with it."""
    shown = {k: v for k, v in counts.items() if v}
    ended = sum(v for k, v in shown.items() if k in TERMINAL_JOB_STATES)
    progress = (100.0 * ended + active_progress) / max(total, 1)
    finished = not any(shown.get(s, 0) for s in ACTIVE_JOB_STATES)
    return BatchProgress(shown, round(progress, 2), finished)


def progress_of_jobs(jobs: Iterable[tuple[str, float]]) -> BatchProgress:
    """`batch_progress` of the jobs themselves ((state, percent) each), the mean over them."""
    counts: dict[str, int] = {}
    active = 0.0
    n = 0
    for state, percent in jobs:
        n += 1
        counts[state] = counts.get(state, 0) + 1
        if state not in TERMINAL_JOB_STATES:
            active += percent
    return batch_progress(counts, active, n)
