"""A running stage's heartbeat on its job's row, and what recovery reads of it.

Why on the row: whether a worker still runs a job used to be read from Redis (a stage lock key
found by SCAN), so losing Redis, or a write that landed in Redis but not in PostgreSQL, left the
two telling different stories and no rule to settle them. The row is the job's truth: the worker
that runs a stage writes its name and `heartbeat_at` there when the stage starts and every quarter
of the lease while it runs; recovery calls a job *running* only while that heartbeat is younger
than the lease, and *stalled* otherwise (the shape of procrastinate's stalled-jobs query).

Each beat is fenced by the attempt that wrote it (the row's `stage_runs` when the stage started):
a worker whose job ended, or was taken over by a later attempt, changes nothing by beating.
"""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import Engine, and_, func, literal, select, update

from bayesian_fields_service.records.tables import jobs

_ACTIVE = ("queued", "running")


def _lease_start(lease_s: float):  # noqa: ANN202 (an SQL expression)
    return func.now() - func.make_interval(0, 0, 0, 0, 0, 0, literal(float(lease_s)))


def beat(database: Engine, tenant: str, job_id: str, worker: str, attempt: int) -> bool:
    """`worker` runs attempt `attempt` of the job's current stage, now. False when the job ended
    or a later attempt runs it (the caller stops beating)."""
    with database.begin() as conn:
        moved = conn.execute(
            update(jobs)
            .where(
                jobs.c.tenant == tenant,
                jobs.c.id == job_id,
                jobs.c.stage_runs == attempt,
                jobs.c.state.in_(_ACTIVE),
            )
            .values(worker=worker, heartbeat_at=func.now())
        )
    return bool(moved.rowcount)


def stage_ended(database: Engine, tenant: str, job_id: str, worker: str) -> None:
    """`worker` no longer runs a stage of the job (the stage returned, whatever its outcome); the
    heartbeat stays as the time of its last activity."""
    with database.begin() as conn:
        conn.execute(
            update(jobs)
            .where(jobs.c.tenant == tenant, jobs.c.id == job_id, jobs.c.worker == worker)
            .values(worker=None, heartbeat_at=func.now())
        )


@dataclass(frozen=True)
class DispatchedJob:
    """What recovery needs of a dispatched, unfinished job's row."""

    tenant: str
    id: str
    stages_done: tuple[str, ...]
    recoveries: int
    running: bool  # a worker beat its row within the lease


def dispatched_jobs(database: Engine, lease_s: float) -> list[DispatchedJob]:
    """Every dispatched, unfinished job, each with whether a worker's heartbeat is fresh. One
    statement over the partial index of dispatched jobs."""
    fresh = and_(jobs.c.worker.is_not(None), jobs.c.heartbeat_at > _lease_start(lease_s))
    query = (
        select(jobs.c.tenant, jobs.c.id, jobs.c.stages_done, jobs.c.recoveries, fresh.label("running"))
        .where(jobs.c.dispatched_at.is_not(None), jobs.c.state.in_(_ACTIVE))
        .order_by(jobs.c.id)
    )
    with database.connect() as conn:
        return [
            DispatchedJob(r.tenant, r.id, tuple(r.stages_done or ()), int(r.recoveries), bool(r.running))
            for r in conn.execute(query)
        ]
