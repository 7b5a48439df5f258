"""The statements of the waiting queue, which is the `jobs` table (`jobs.queue` says why):
the backlog per tenant, taking a tenant's head, putting a job back, a job's position, the recent
dispatches, and the admission count under its tenant's transaction lock.

A job *waits* while its row is queued with no `dispatched_at` (`WAITING`, the partial index
``ix_jobs_waiting`` on (tenant, priority, created_at, id)); it is *dispatched* once stamped and
until its row ends (`DISPATCHED`). The fair-share rules (stride scheduling, admission limits)
are the domain's; these only read and move rows.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from datetime import datetime
from typing import Any

from sqlalchemy import Connection, and_, func, literal, select, tuple_, update

from bayesian_fields_service.records.locks import lock_key
from bayesian_fields_service.records.tables import jobs

_ACTIVE = ("queued", "running")
WAITING = and_(jobs.c.state == "queued", jobs.c.dispatched_at.is_(None))
DISPATCHED = and_(jobs.c.dispatched_at.is_not(None), jobs.c.state.in_(_ACTIVE))


def admission_count(conn: Connection, tenant: str) -> int:
    """In the caller's inserting transaction: take the tenant's admission lock (held until commit,
    so two inserting transactions never both see the last free slot) and count its unfinished
    jobs."""
    conn.execute(select(func.pg_advisory_xact_lock(lock_key("admission", tenant))))
    active = conn.execute(
        select(func.count()).select_from(jobs).where(jobs.c.tenant == tenant, jobs.c.state.in_(_ACTIVE))
    ).scalar_one()
    return int(active)


def waiting_counts(conn: Connection) -> list[tuple[str, str, int]]:
    """(tenant, priority, waiting jobs) of every tenant and priority that has any: one grouped
    scan of the waiting index."""
    rows = conn.execute(
        select(jobs.c.tenant, jobs.c.priority, func.count())
        .where(WAITING)
        .group_by(jobs.c.tenant, jobs.c.priority)
    ).all()
    return [(tenant, priority, int(n)) for tenant, priority, n in rows]


def dispatched_counts(conn: Connection) -> dict[str, int]:
    """Dispatched, unfinished jobs per tenant that has any."""
    rows = conn.execute(select(jobs.c.tenant, func.count()).where(DISPATCHED).group_by(jobs.c.tenant)).all()
    return {tenant: int(n) for tenant, n in rows}


def waiting_by_tenant(conn: Connection) -> dict[str, int]:
    """Waiting jobs per tenant that has any."""
    rows = conn.execute(select(jobs.c.tenant, func.count()).where(WAITING).group_by(jobs.c.tenant))
    return {tenant: int(n) for tenant, n in rows}


def take(conn: Connection, tenant: str, priorities: Sequence[str]) -> dict[str, Any] | None:
    """Stamp the tenant's head waiting job dispatched, trying `priorities` in order (each oldest
    first), and return its row; None when nothing waits or what waits is locked by another
    transaction right now (``FOR UPDATE SKIP LOCKED``: e.g. being cancelled)."""
    for priority in priorities:
        head = (
            select(jobs.c.id)
            .where(WAITING, jobs.c.tenant == tenant, jobs.c.priority == priority)
            .order_by(jobs.c.created_at, jobs.c.id)
            .limit(1)
            .with_for_update(skip_locked=True)
            .scalar_subquery()
        )
        row = conn.execute(
            update(jobs).where(jobs.c.id == head).values(dispatched_at=func.now()).returning(*jobs.c)
        ).mappings().first()  # fmt: skip
        if row is not None:
            return dict(row)
    return None


def dispatched_pairs(conn: Connection) -> list[tuple[str, str]]:
    """(tenant, id) of every dispatched, unfinished job, by id."""
    rows = conn.execute(select(jobs.c.tenant, jobs.c.id).where(DISPATCHED).order_by(jobs.c.id))
    return [(r.tenant, r.id) for r in rows]


def requeue(conn: Connection, tenant: str, job_id: str, *, recovered: bool) -> bool:
    """A dispatched job back to waiting, as *queued* (its `dispatched_at` cleared; `recovered`
    adds one to its `recoveries`). False when it ended or was not dispatched."""
    moved = conn.execute(
        update(jobs)
        .where(jobs.c.tenant == tenant, jobs.c.id == job_id, DISPATCHED)
        .values(
            dispatched_at=None,
            state="queued",
            recoveries=jobs.c.recoveries + (1 if recovered else 0),
            worker=None,  # whatever held it is gone: its next delivery claims it afresh
        )
    )
    return bool(moved.rowcount)


def waits(conn: Connection, tenant: str, job_id: str) -> bool:
    """Whether the job waits in its tenant's queue."""
    found = conn.execute(
        select(jobs.c.id).where(WAITING, jobs.c.tenant == tenant, jobs.c.id == job_id)
    ).first()
    return found is not None


def count_ahead(conn: Connection, tenant: str, job_id: str, priority: str, created_at: datetime) -> int:
    """Waiting jobs of the tenant dispatched before this one: interactive before bulk, each by
    (created_at, id). One counted range of the waiting index."""
    mine = tuple_(jobs.c.created_at, jobs.c.id) < tuple_(literal(created_at), literal(job_id))
    ahead = and_(jobs.c.priority == priority, mine)
    if priority == "bulk":
        ahead = (jobs.c.priority == "interactive") | ahead
    n = conn.execute(select(func.count()).select_from(jobs).where(WAITING, jobs.c.tenant == tenant, ahead))
    return int(n.scalar_one())


def dispatches_since(conn: Connection, tenant: str, since_epoch_s: float) -> tuple[int, datetime | None]:
    """(how many, the first one's time) of the tenant's jobs dispatched after `since_epoch_s`."""
    since = func.to_timestamp(since_epoch_s)
    n, first = conn.execute(
        select(func.count(), func.min(jobs.c.dispatched_at)).where(
            jobs.c.tenant == tenant, jobs.c.dispatched_at.is_not(None), jobs.c.dispatched_at > since
        )
    ).one()
    return int(n), first


def dispatched_ids(conn: Connection, tenant: str, among: Iterable[str] | None = None) -> list[str]:
    """Ids of the tenant's dispatched, unfinished jobs (only those `among` when given)."""
    query = select(jobs.c.id).where(DISPATCHED, jobs.c.tenant == tenant)
    if among is not None:
        query = query.where(jobs.c.id.in_(list(among)))
    return [r.id for r in conn.execute(query)]
