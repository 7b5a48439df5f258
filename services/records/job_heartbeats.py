"""A job's current stage claimed on its row, its heartbeat, and what recovery reads of them.

Why on the row: whether a worker runs a job used to be read from Redis (a stage lock found by
SCAN, and the broker's own lists for a message that waits), so losing Redis, or a write that landed
in one store and not the other, left them telling different stories and no rule to settle them.
The row is the job's truth:

- a worker that takes a stage message *claims* the job (`claim`): it writes its name in `worker`
  and `heartbeat_at`, unless another worker holds a claim whose heartbeat is younger than the
  lease; a duplicate delivery of the stage therefore waits (or finds the stage done), and a
  crashed holder's claim lapses after the lease, or at once when its process is known dead;
- while the stage runs, the worker beats `heartbeat_at` every quarter of the lease (`beat`), fenced
  by its own name (a worker whose claim was taken over, or whose job ended, changes nothing) and
  reading the job's cancel flag back, so a cancel reaches the stage without Redis;
- when the stage returns, whatever its outcome, the claim is given up (`stage_ended`);
- recovery (`control.recovery`) reads every dispatched, unfinished job in one statement
  (`dispatched_jobs`): running (claimed with a fresh heartbeat), claimed by a worker gone silent,
  or unclaimed (its message waits, or was lost), with how long it has been idle. The shape of
  procrastinate's stalled-jobs query.

Worker names are ``host:pid:process start:random`` (`worker.tasks`), unique per claim.
"""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import Engine, and_, func, literal, or_, select, update

from bayesian_fields_service.records.tables import jobs

_ACTIVE = ("queued", "running")


def _ago(seconds: float):  # noqa: ANN202 (an SQL expression)
    return func.now() - func.make_interval(0, 0, 0, 0, 0, 0, literal(float(seconds)))


@dataclass(frozen=True)
class Claim:
    """The outcome of `claim`: taken, or who holds it and for how long at most."""

    taken: bool
    holder: str | None = None
    remaining_s: float = 0.0  # until the holder's claim lapses unless it beats again
    ended: bool = False  # the job is no longer active: nothing to run


def claim(
    database: Engine, tenant: str, job_id: str, worker: str, lease_s: float, *, dead_owner: str | None = None
) -> Claim:
    """Claim the job for `worker`: taken when nobody holds it, the holder's heartbeat is older than
    `lease_s`, or the holder is `dead_owner` (a process of this host known to be gone)."""
    free = or_(
        jobs.c.worker.is_(None),
        jobs.c.heartbeat_at.is_(None),
        jobs.c.heartbeat_at <= _ago(lease_s),
        jobs.c.worker == worker,
        *([jobs.c.worker == dead_owner] if dead_owner is not None else []),
    )
    mine = and_(jobs.c.tenant == tenant, jobs.c.id == job_id)
    with database.begin() as conn:
        taken = conn.execute(
            update(jobs)
            .where(mine, jobs.c.state.in_(_ACTIVE), free)
            .values(worker=worker, heartbeat_at=func.now())
            .returning(jobs.c.id)
        ).first()
        if taken is not None:
            return Claim(True)
        row = conn.execute(
            select(
                jobs.c.state,
                jobs.c.worker,
                func.extract("epoch", jobs.c.heartbeat_at - _ago(lease_s)).label("remaining"),
            ).where(mine)
        ).first()
    if row is None or row.state not in _ACTIVE:
        return Claim(False, ended=True)
    return Claim(False, holder=row.worker, remaining_s=max(0.0, float(row.remaining or 0.0)))


@dataclass(frozen=True)
class Beat:
    """What a heartbeat found: whether this worker still holds the job, and its cancel flag."""

    held: bool
    cancel_requested: bool = False


def beat(database: Engine, tenant: str, job_id: str, worker: str) -> Beat:
    """`worker` still runs the job, now; reads back whether a cancel was accepted."""
    with database.begin() as conn:
        row = conn.execute(
            update(jobs)
            .where(
                jobs.c.tenant == tenant,
                jobs.c.id == job_id,
                jobs.c.worker == worker,
                jobs.c.state.in_(_ACTIVE),
            )  # fmt: skip
            .values(heartbeat_at=func.now())
            .returning(jobs.c.cancel_requested)
        ).first()
    return Beat(False) if row is None else Beat(True, bool(row.cancel_requested))


def stage_ended(database: Engine, tenant: str, job_id: str, worker: str) -> None:
    """`worker` gives its claim up (the stage returned, whatever its outcome); the heartbeat stays
    as the time of the job's last activity."""
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
    claimed: bool  # a worker's name is on the row
    running: bool  # ... and its heartbeat is younger than the lease
    idle_s: float  # since its last heartbeat, stage end or dispatch


def stalled_clause(lease_s: float):  # noqa: ANN201 (an SQL expression)
    """A dispatched, unfinished job whose worker's claim went silent: a worker's name on the row
    and a heartbeat older than the lease (recovery's suspects that are claimed and not running;
    `records.fleet_metrics` counts them for `/metrics`)."""
    return and_(
        jobs.c.dispatched_at.is_not(None),
        jobs.c.state.in_(_ACTIVE),
        jobs.c.worker.is_not(None),
        or_(jobs.c.heartbeat_at.is_(None), jobs.c.heartbeat_at <= _ago(lease_s)),
    )


def dispatched_jobs(database: Engine, lease_s: float) -> list[DispatchedJob]:
    """Every dispatched, unfinished job with its claim and idleness. One statement over the
    partial index of dispatched jobs."""
    claimed = jobs.c.worker.is_not(None)
    fresh = and_(claimed, jobs.c.heartbeat_at > _ago(lease_s))
    last = func.greatest(jobs.c.heartbeat_at, jobs.c.dispatched_at)
    query = (
        select(
            jobs.c.tenant,
            jobs.c.id,
            jobs.c.stages_done,
            jobs.c.recoveries,
            claimed.label("claimed"),
            fresh.label("running"),
            func.extract("epoch", func.now() - last).label("idle_s"),
        )  # fmt: skip
        .where(jobs.c.dispatched_at.is_not(None), jobs.c.state.in_(_ACTIVE))
        .order_by(jobs.c.id)
    )
    with database.connect() as conn:
        return [
            DispatchedJob(
                r.tenant,
                r.id,
                tuple(r.stages_done or ()),
                int(r.recoveries),
                bool(r.claimed),
                bool(r.running),
                float(r.idle_s or 0.0),
            )  # fmt: skip
            for r in conn.execute(query)
        ]
