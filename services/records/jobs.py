"""The statements over `jobs` rows: load (plain or locked), insert, write, page, count.

Why here and not beside `JobRecord`: the rules (the merge, a cancel winning over a success, what a
job's end writes) belong to the jobs domain (`jobs.store`), which opens the unit of work
(`records.begin`) and calls these with its connection; this module only knows the table. Rows go
in as column dicts and come back as SQLAlchemy row mappings.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from sqlalchemy import JSON, Connection, RowMapping, func, insert, select, update
from sqlalchemy.dialects.postgresql import JSONB

from bayesian_fields_service.records.tables import ACTIVE_JOB_STATES, jobs

#: Row states of a job that has not ended.
ACTIVE_STATES = ACTIVE_JOB_STATES


def load(conn: Connection, tenant: str, job_id: str, *, lock: bool = False) -> RowMapping | None:
    """The job's row, or None; `lock`: held ``FOR UPDATE`` until `conn`'s transaction ends (the
    row lock every merge-write takes)."""
    query = select(jobs).where(jobs.c.tenant == tenant, jobs.c.id == job_id)
    if lock:
        query = query.with_for_update()
    return conn.execute(query).mappings().first()


def load_many(conn: Connection, tenant: str, job_ids: Sequence[str]) -> list[RowMapping]:
    """The rows of those `job_ids` that exist (one query)."""
    return list(conn.execute(select(jobs).where(jobs.c.tenant == tenant, jobs.c.id.in_(job_ids))).mappings())


def insert_row(conn: Connection, row: dict[str, Any]) -> None:
    """A new job's row."""
    conn.execute(insert(jobs).values(**row))


def write_row(conn: Connection, row: dict[str, Any]) -> None:
    """Overwrite the job's row (tenant and id from `row`) with `row`'s columns."""
    conn.execute(update(jobs).where(jobs.c.tenant == row["tenant"], jobs.c.id == row["id"]).values(**row))


def insert_many(conn: Connection, rows: list[dict[str, Any]]) -> None:
    """Insert job rows (dicts with the same keys) with PostgreSQL's COPY, in `conn`'s transaction:
    a 5,000-job batch's rows in one stream (an executemany of INSERTs took 0.45 s of a 2 s submit).
    JSON columns go as JSON text, which COPY's text format parses into jsonb."""
    if not rows:
        return
    names = list(rows[0])
    documents = {c.name for c in jobs.columns if isinstance(c.type, JSON | JSONB)}
    cursor = conn.connection.driver_connection.cursor()  # type: ignore[union-attr]
    with cursor.copy(f"COPY {jobs.name} ({', '.join(names)}) FROM STDIN") as copy:
        for row in rows:
            copy.write_row([json.dumps(row[n]) if n in documents else row[n] for n in names])


def page(
    conn: Connection,
    tenant: str,
    *,
    states: Sequence[str] | None = None,
    scene_id: str | None = None,
    batch_id: str | None = None,
    before: str | None = None,
    limit: int,
) -> list[RowMapping]:
    """Up to `limit` of the tenant's rows, newest first (descending id), with ids below `before`
    when given: a keyset page over the (tenant, id) order."""
    query = select(jobs).where(jobs.c.tenant == tenant)
    if states is not None:
        query = query.where(jobs.c.state.in_(list(states)))
    if scene_id is not None:
        query = query.where(jobs.c.scene_id == scene_id)
    if batch_id is not None:
        query = query.where(jobs.c.batch_id == batch_id)
    if before is not None:
        query = query.where(jobs.c.id < before)
    return list(conn.execute(query.order_by(jobs.c.id.desc()).limit(limit)).mappings().all())


def count_active(conn: Connection, tenant: str | None = None) -> int:
    """Queued or running jobs (of one tenant, or of all)."""
    query = select(func.count()).select_from(jobs).where(jobs.c.state.in_(ACTIVE_STATES))
    if tenant is not None:
        query = query.where(jobs.c.tenant == tenant)
    return int(conn.execute(query).scalar_one())


def active_pairs(conn: Connection) -> list[tuple[str, str]]:
    """(tenant, job id) of every job whose row says queued or running, by id."""
    rows = conn.execute(
        select(jobs.c.tenant, jobs.c.id).where(jobs.c.state.in_(ACTIVE_STATES)).order_by(jobs.c.id)
    )
    return [(r.tenant, r.id) for r in rows]


def active_on_scene(conn: Connection, tenant: str, scene_id: str) -> RowMapping | None:
    """(id, state) of one queued or running job on the scene, or None."""
    return (
        conn.execute(
            select(jobs.c.id, jobs.c.state)
            .where(jobs.c.tenant == tenant, jobs.c.scene_id == scene_id, jobs.c.state.in_(ACTIVE_STATES))
            .limit(1)
        )
        .mappings()
        .first()
    )
