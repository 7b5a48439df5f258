"""Accounting: what each job cost (CPU-seconds, GPU-seconds by stage, bytes stored) and the
per-tenant, per-day totals behind ``GET /v1/usage``.

Per job: `JobUsage` on the job record, filled by the worker after every stage execution (retries
and crashed runs that reached the end of their stage included: they used the machine too).
- CPU-seconds: the worker process's CPU time (`time.process_time`, all its threads: decode and
  segmentation prefetch threads included) over the stage; a pool process runs one stage at a time.
- GPU-seconds: the stage's wall time when the worker's device is CUDA (the process holds the GPU for
  the whole stage), 0 on a CPU worker.
- bytes stored: the size of everything under the job's prefix (``jobs/<id>/``: stage markers,
  intermediate arrays, result) after the stage; the scene and its shared caches are not a job's.

Per tenant and day (UTC): the ``usage_ledger`` table of the records database. Every stage
execution is one row written by the worker that ran it (`record_stage`); every job end is one row
written in the same transaction as the job's terminal state (`end_rows`, queued by the jobs
domain whoever ends the job: a worker, a cancel of a waiting job, a batch cancel, recovery), so a
job cancelled before any worker saw it is counted like any other. Each row has a unique
``entry_id``, so a retried write never counts twice; the totals are one aggregate query over the
(tenant, recorded_at) index, and a Redis loss changes nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, date, datetime, time, timedelta
from typing import Any, Protocol

from pydantic import BaseModel, Field, computed_field
from sqlalchemy import Engine

from bayesian_fields_service import records
from bayesian_fields_service.records import usage as ledger


class JobUsage(BaseModel):
    """Resources one job used (shown in GET /v1/jobs/{id} as ``usage``)."""

    cpu_seconds: dict[str, float] = Field(
        default_factory=dict, description="CPU-seconds (process time) by stage, summed over its runs."
    )
    gpu_seconds: dict[str, float] = Field(
        default_factory=dict, description="GPU-seconds (wall time on a CUDA device) by stage; 0 on CPU."
    )
    bytes_stored: int = Field(0, ge=0, description="Bytes under the job's prefix after its last stage.")

    @computed_field(description="Sum of cpu_seconds over the stages.")  # type: ignore[prop-decorator]
    @property
    def cpu_seconds_total(self) -> float:
        return round(sum(self.cpu_seconds.values()), 3)

    @computed_field(description="Sum of gpu_seconds over the stages.")  # type: ignore[prop-decorator]
    @property
    def gpu_seconds_total(self) -> float:
        return round(sum(self.gpu_seconds.values()), 3)

    def add_stage(self, stage: str, cpu_s: float, gpu_s: float, bytes_stored: int) -> JobUsage:
        return JobUsage(
            cpu_seconds={**self.cpu_seconds, stage: round(self.cpu_seconds.get(stage, 0.0) + cpu_s, 3)},
            gpu_seconds={**self.gpu_seconds, stage: round(self.gpu_seconds.get(stage, 0.0) + gpu_s, 3)},
            bytes_stored=bytes_stored,
        )

    @staticmethod
    def merged(old: JobUsage, new: JobUsage) -> JobUsage:
        """Two writers' views of one job: usage only grows per stage, so the larger one is newer."""
        stages = set(old.cpu_seconds) | set(new.cpu_seconds) | set(old.gpu_seconds) | set(new.gpu_seconds)
        return JobUsage(
            cpu_seconds={s: max(old.cpu_seconds.get(s, 0.0), new.cpu_seconds.get(s, 0.0)) for s in stages},
            gpu_seconds={s: max(old.gpu_seconds.get(s, 0.0), new.gpu_seconds.get(s, 0.0)) for s in stages},
            bytes_stored=new.bytes_stored,
        )


class EndedJob(Protocol):
    """What `end_rows` reads of a job record."""

    id: str
    tenant: str
    finished_at: datetime | None
    usage: JobUsage

    @property
    def state(self) -> Any: ...


def record_stage(database: Engine, tenant: str, job_id: str, stage: str, run: int, cpu_s: float, gpu_s: float,
                 when: datetime) -> None:  # fmt: skip
    """One stage execution's row (entry ``<job>.<stage>.<run>``: written once however often tried)."""
    with records.begin(database) as conn:
        ledger.insert_entry(conn, {"entry_id": f"{job_id}.{stage}.{run}", "tenant": tenant, "job_id": job_id, "kind": "stage",
                       "stage": stage, "cpu_s": cpu_s, "gpu_s": gpu_s, "recorded_at": when})  # fmt: skip


def end_rows(ended: Sequence[EndedJob]) -> list[tuple[str, str, str, str, int, datetime]]:
    """The ledger rows of the jobs' ends (outcome, the bytes each leaves stored), for the unit of
    work that made them terminal (entry ``<job>.end``: once per job, a duplicate entry id is
    dropped by the records). One statement however many."""
    now = datetime.now(UTC)
    return [
        (f"{job.id}.end", job.tenant, job.id, str(getattr(job.state, "value", job.state)), job.usage.bytes_stored,
         job.finished_at or now)
        for job in ended
    ]  # fmt: skip


def _empty() -> dict[str, Any]:
    return {"jobs": 0, "jobs_by_state": {}, "stage_runs": 0, "cpu_seconds": 0.0, "gpu_seconds": 0.0,
            "bytes_stored": 0, "by_stage": {}}  # fmt: skip


def _add(totals: dict[str, Any], kind: str, stage: str | None, state: str | None, n: int, cpu: float, gpu: float,
         size: int) -> None:  # fmt: skip
    if kind == "end":
        totals["jobs"] += n
        totals["jobs_by_state"][state or "?"] = totals["jobs_by_state"].get(state or "?", 0) + n
        totals["bytes_stored"] += size
        return
    totals["stage_runs"] += n
    totals["cpu_seconds"] = round(totals["cpu_seconds"] + cpu, 3)
    totals["gpu_seconds"] = round(totals["gpu_seconds"] + gpu, 3)
    by = totals["by_stage"].setdefault(stage or "?", {"cpu_seconds": 0.0, "gpu_seconds": 0.0})
    by["cpu_seconds"] = round(by["cpu_seconds"] + cpu, 3)
    by["gpu_seconds"] = round(by["gpu_seconds"] + gpu, 3)


def tenant_usage(database: Engine, tenant: str, start: date, end: date) -> dict[str, Any]:
    """Totals of `tenant` per day in [start, end] (UTC, inclusive) and over the period: one
    aggregate over the tenant's ledger rows of the period."""
    low = datetime.combine(start, time(), UTC)
    high = datetime.combine(end + timedelta(days=1), time(), UTC)
    with records.connect(database) as conn:
        rows = ledger.daily_totals(conn, tenant, low, high)
    days: dict[str, dict[str, Any]] = {}
    total = _empty()
    for when, kind, stage, state, n, cpu, gpu, size in rows:
        for totals in (days.setdefault(when.isoformat(), _empty()), total):
            _add(totals, kind, stage, state, int(n), float(cpu), float(gpu), int(size))
    return {"tenant": tenant, "from": start.isoformat(), "to": end.isoformat(), "total": total,
            "days": [{"day": d, **t} for d, t in sorted(days.items())]}  # fmt: skip
