"""The statements `/metrics` reads the fleet's state by: active jobs by state, the callback outbox's
depth and oldest open event, whether a control process holds the leader's lease, and the stalled
jobs (a worker's claim whose heartbeat is older than the lease).

Why one read of its own: a scrape comes every 15-30 s from every Prometheus replica, so each
statement here is bounded by a partial index (active jobs: ``ix_jobs_active``; open callbacks:
``ix_callback_outbox_due``; the lease: its primary key), never a scan of the finished history.
Finished jobs are counted by the job-duration histogram's ``_count`` (by outcome) instead.
"""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import Connection, Engine, and_, func, select

from bayesian_fields_service.records.job_heartbeats import stalled_clause
from bayesian_fields_service.records.tables import ACTIVE_JOB_STATES, callback_outbox, control_leases, jobs


@dataclass(frozen=True)
class FleetRows:
    """One reading of the rows `/metrics` reports (module docstring)."""

    jobs_by_state: dict[str, int]  # every active state, 0 where none
    outbox_open: int  # callbacks neither delivered nor dropped
    outbox_oldest_age_s: float  # age of the oldest open callback; 0 when none is open
    leader_held: bool  # the lease `lease_name` is held by someone and not expired
    stalled_jobs: int


def read(database: Engine, *, lease_name: str, stage_lease_s: float) -> FleetRows:
    """The fleet's rows now, in the database's clock (`stage_lease_s`: the stage claim's lease);
    raises what reaching the database raised."""
    with database.connect() as conn:
        return _read(conn, lease_name, stage_lease_s)


def _read(conn: Connection, lease_name: str, stage_lease_s: float) -> FleetRows:
    counted = {
        str(state): int(n)
        for state, n in conn.execute(
            select(jobs.c.state, func.count())
            .where(jobs.c.state.in_(ACTIVE_JOB_STATES))
            .group_by(jobs.c.state)
        )
    }
    by_state = {state: int(counted.get(state, 0)) for state in ACTIVE_JOB_STATES}
    open_ = and_(callback_outbox.c.delivered_at.is_(None), callback_outbox.c.dropped_at.is_(None))
    depth, age = conn.execute(
        select(
            func.count(),
            func.coalesce(func.extract("epoch", func.now() - func.min(callback_outbox.c.created_at)), 0),
        ).where(open_)
    ).one()
    leader = conn.execute(
        select(func.count())
        .select_from(control_leases)
        .where(control_leases.c.name == lease_name, control_leases.c.expires_at > func.now())
    ).scalar_one()
    stalled = conn.execute(
        select(func.count()).select_from(jobs).where(stalled_clause(stage_lease_s))
    ).scalar_one()
    return FleetRows(by_state, int(depth), max(0.0, float(age)), bool(leader), int(stalled))
