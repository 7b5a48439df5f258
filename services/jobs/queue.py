"""The waiting queue is the `jobs` table: fair share between tenants, admission and queue position.

Why the table and not Redis lists: a job that is committed is queued, in the same transaction
that stores it, so there is no window in which a job exists and waits nowhere, and losing Redis
loses no waiting work. A job *waits* while its row is queued with no `dispatched_at`; the control
process's dispatcher (`control.dispatcher`) takes the head of one tenant's queue with
``FOR UPDATE SKIP LOCKED`` and stamps `dispatched_at` before it sends the Celery chain; recovery
clears the stamp of a dispatched job whose message Redis lost (`requeue`), which puts it back at
the front (the queue is ordered by creation, and it is older than what still waits).

Order within a tenant: ``interactive`` before ``bulk``, each oldest first (the partial index
``ix_jobs_waiting`` on (tenant, priority, created_at, id)). Between tenants: stride scheduling
(`StrideClock`): each dispatch advances the tenant's *pass* by ``1 / weight``; the backlogged
tenant with the lowest pass goes next; a tenant that was idle rejoins at the current virtual time,
so it neither banks credit nor waits behind the others' backlog. The passes live in the leader's
memory: a new leader starts them level, which is fair from then on.

Admission (`admit`): a tenant's unfinished jobs may not exceed its waiting bound plus its dispatch
bound. Counted in the inserting transaction under a per-tenant transaction lock, so two API
processes can never both see the last free slot (100 concurrent submissions at a quota of 16
accept exactly 16), and nothing is ever to be given back: a job stops counting when its row ends.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Literal, Protocol

from sqlalchemy import Engine

from bayesian_fields_service import records
from bayesian_fields_service.records import queue
from bayesian_fields_service.records.leases import Fence, assert_lease

Priority = Literal["interactive", "bulk"]
PRIORITIES: tuple[Priority, ...] = ("interactive", "bulk")  # the order within a tenant's queue

#: Seconds of dispatch history used for a tenant's dispatch rate (the estimated start).
RATE_WINDOW_S = 600.0


class AdmissionRefused(Exception):
    """The tenant's unfinished jobs would exceed its admission limit."""

    def __init__(self, active: int, limit: int, asked: int) -> None:
        super().__init__(f"{active} unfinished jobs, limit {limit}, {asked} more asked")
        self.active, self.limit, self.asked = active, limit, asked


@dataclass(frozen=True)
class TenantQuota:
    """A tenant's admission quota as a submission left it: `used` of `limit` unfinished jobs
    (what the API reports in its RateLimit headers)."""

    limit: int
    used: int

    @property
    def remaining(self) -> int:
        return max(0, self.limit - self.used)


def admission_limit(max_waiting: int, max_dispatched: int) -> int:
    """Unfinished jobs a tenant may have: its waiting bound plus what may be dispatched."""
    return max_waiting + max_dispatched


class AdmissionCount(Protocol):
    """What `admit` needs of the unit of work (`ports.JobTx`)."""

    def admission_count(self, tenant: str) -> int: ...


def admit(tx: AdmissionCount, tenant: str, asked: int, limit: int) -> int:
    """In the caller's inserting transaction: hold the tenant's admission lock (until commit) and
    count its unfinished jobs; `AdmissionRefused` when `asked` more would pass `limit`. Returns
    the count before the new jobs."""
    active = tx.admission_count(tenant)
    if active + asked > limit:
        raise AdmissionRefused(active, limit, asked)
    return active


@dataclass
class TenantBacklog:
    """What the dispatcher needs to choose a tenant (one snapshot per round, kept up to date by
    the round itself as it takes jobs)."""

    tenant: str
    interactive: int
    bulk: int
    dispatched: int
    pass_value: float = 0.0


@dataclass
class StrideClock:
    """Weighted fair share by stride scheduling (module docstring); the leader's memory."""

    passes: dict[str, float] = field(default_factory=dict)
    vtime: float = 0.0
    _backlogged: set[str] = field(default_factory=set)

    def observe(self, backlog: list[TenantBacklog]) -> None:
        """Set each tenant's pass; one that was not backlogged last time rejoins at `vtime`."""
        now_backlogged = {b.tenant for b in backlog if b.interactive + b.bulk > 0}
        for tenant in now_backlogged - self._backlogged:
            self.passes[tenant] = max(self.passes.get(tenant, 0.0), self.vtime)
        self._backlogged = now_backlogged
        for b in backlog:
            b.pass_value = self.passes.get(b.tenant, self.vtime)

    def advance(self, pick: TenantBacklog, weight: float) -> None:
        self.vtime = pick.pass_value
        pick.pass_value += 1.0 / weight
        self.passes[pick.tenant] = pick.pass_value


def choose(backlog: list[TenantBacklog], limit: int, skip: set[str]) -> TenantBacklog | None:
    """The tenant to dispatch next: lowest pass among those with waiting jobs and room under the
    dispatch bound; on a tie, one with an interactive job first."""
    ready = [
        b for b in backlog if b.tenant not in skip and b.interactive + b.bulk > 0 and b.dispatched < limit
    ]
    if not ready:
        return None
    return min(ready, key=lambda b: (b.pass_value, 0 if b.interactive else 1, b.tenant))


class JobQueue:
    """Reads and moves of the waiting queue (the statements of `records.queue`; module docstring)."""

    def __init__(self, database: Engine) -> None:
        self.database = database

    # ---- dispatcher side -----------------------------------------------------------------------
    def backlog(self) -> list[TenantBacklog]:
        """Every tenant with waiting or dispatched jobs: two grouped index scans."""
        with records.connect(self.database) as conn:
            waiting = queue.waiting_counts(conn)
            dispatched = queue.dispatched_counts(conn)
        out: dict[str, TenantBacklog] = {}
        for tenant, priority, n in waiting:
            b = out.setdefault(tenant, TenantBacklog(tenant, 0, 0, 0))
            setattr(b, priority, n)
        for tenant, n in dispatched.items():
            out.setdefault(tenant, TenantBacklog(tenant, 0, 0, 0)).dispatched = n
        return [out[t] for t in sorted(out)]

    def take(self, tenant: str, fence: Fence | None = None) -> dict[str, Any] | None:
        """Stamp the tenant's next waiting job dispatched and return its row (None: nothing waits,
        or what waits is being changed by another transaction right now, e.g. cancelled). With a
        `fence`, only while that lease is still current (`records.leases.LeaseLost` otherwise)."""
        with records.begin(self.database) as conn:
            if fence is not None:
                assert_lease(conn, fence)
            return queue.take(conn, tenant, PRIORITIES)

    def undo_take(self, tenant: str, job_id: str) -> None:
        """Put a job whose chain could not be sent back where it was (the broker was down)."""
        self.requeue(tenant, job_id)

    # ---- recovery side -------------------------------------------------------------------------
    def dispatched_jobs(self) -> list[tuple[str, str]]:
        """(tenant, id) of every dispatched, unfinished job."""
        with records.connect(self.database) as conn:
            return queue.dispatched_pairs(conn)

    def requeue(
        self, tenant: str, job_id: str, fence: Fence | None = None, *, recovered: bool = False
    ) -> bool:
        """Back to the queue (front: it is older than what still waits), as *queued* again even if
        a stage of it had started: no stage runs now, and only queued rows are waiting work. False
        when the job ended or was not dispatched meanwhile. Fenced as `take` is. `recovered`:
        recovery's requeue of a job that lost its worker, counted in its `recoveries`."""
        with records.begin(self.database) as conn:
            if fence is not None:
                assert_lease(conn, fence)
            return queue.requeue(conn, tenant, job_id, recovered=recovered)

    # ---- reading (API, metrics) ----------------------------------------------------------------
    def position(self, tenant: str, job_id: str, priority: str, created_at: datetime) -> int | None:
        """1 for the tenant's next job to be dispatched; None when the job does not wait. One
        counted range of the waiting index (interactive jobs first, then bulk, oldest first)."""
        with records.connect(self.database) as conn:
            if not queue.waits(conn, tenant, job_id):
                return None
            return queue.count_ahead(conn, tenant, job_id, priority, created_at) + 1

    def dispatch_rate(self, tenant: str, now: float | None = None) -> float:
        """The tenant's jobs dispatched per second over the last `RATE_WINDOW_S`."""
        now = time.time() if now is None else now
        with records.connect(self.database) as conn:
            n, first = queue.dispatches_since(conn, tenant, now - RATE_WINDOW_S)
        if n < 2 or first is None:
            return 0.0
        return float(n) / max(now - first.timestamp(), 1.0)

    def waiting_by_tenant(self) -> dict[str, int]:
        """Waiting jobs per tenant that has any (the Prometheus gauge and KEDA's measure)."""
        with records.connect(self.database) as conn:
            return queue.waiting_by_tenant(conn)

    def dispatched_ids(self, tenant: str, among: Iterable[str] | None = None) -> list[str]:
        """Ids of the tenant's dispatched, unfinished jobs (at most its dispatch bound)."""
        with records.connect(self.database) as conn:
            return queue.dispatched_ids(conn, tenant, among)
