"""The statements over `usage_ledger` rows: a stage execution's row, the end rows of many jobs in
one statement, and the per-day aggregate of a tenant's rows.

Why entry ids: each row's ``entry_id`` (``<job>.<stage>.<run>``, ``<job>.end``) is unique and
every insert does nothing on a conflict, so a write tried again after an outage counts once.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any

from sqlalchemy import Connection, Integer, cast, func, select, text
from sqlalchemy.dialects.postgresql import insert as pg_insert

from bayesian_fields_service.records.tables import usage_ledger

#: The end rows of many jobs in one statement: arrays unnested (a multi-row VALUES of thousands of
#: rows spends longer compiling than PostgreSQL spends inserting, and PostgreSQL binds at most
#: 65,535 values a statement: a 50,000-job cancel ends them all in one transaction).
_INSERT_ENDS = text(
    "INSERT INTO usage_ledger (entry_id, tenant, job_id, kind, state, bytes_stored, recorded_at) "
    "SELECT e, t, j, 'end', s, b, r FROM unnest(CAST(:e AS varchar[]), CAST(:t AS varchar[]), "
    "CAST(:j AS varchar[]), CAST(:s AS varchar[]), CAST(:b AS bigint[]), CAST(:r AS timestamptz[])) "
    "AS ends(e, t, j, s, b, r) ON CONFLICT (entry_id) DO NOTHING"
)


def insert_entry(conn: Connection, row: dict[str, Any]) -> None:
    """One ledger row (nothing when its ``entry_id`` is there already)."""
    conn.execute(
        pg_insert(usage_ledger).values(**row).on_conflict_do_nothing(index_elements=[usage_ledger.c.entry_id])
    )


def insert_ends(conn: Connection, ends: Sequence[tuple[str, str, str, str, int, datetime]]) -> None:
    """End rows, each (entry id, tenant, job id, state, bytes stored, recorded at), in one
    statement (nothing for an entry id already there)."""
    if not ends:
        return
    e, t, j, s, b, r = (list(column) for column in zip(*ends, strict=True))
    conn.execute(_INSERT_ENDS, {"e": e, "t": t, "j": j, "s": s, "b": b, "r": r})


def daily_totals(conn: Connection, tenant: str, low: datetime, high: datetime) -> list[tuple[Any, ...]]:
    """(day in UTC, kind, stage, state, rows, cpu s, gpu s, bytes) of the tenant's rows recorded
    in [low, high), grouped by day, kind, stage and state, by day: one aggregate."""
    day = func.date(func.timezone("UTC", usage_ledger.c.recorded_at)).label("day")
    query = (
        select(
            day,
            usage_ledger.c.kind,
            usage_ledger.c.stage,
            usage_ledger.c.state,
            func.count(),
            func.coalesce(func.sum(usage_ledger.c.cpu_s), 0.0),
            func.coalesce(func.sum(usage_ledger.c.gpu_s), 0.0),
            cast(func.coalesce(func.sum(usage_ledger.c.bytes_stored), 0), Integer),
        )  # fmt: skip
        .where(
            usage_ledger.c.tenant == tenant,
            usage_ledger.c.recorded_at >= low,
            usage_ledger.c.recorded_at < high,
        )
        .group_by(day, usage_ledger.c.kind, usage_ledger.c.stage, usage_ledger.c.state)
        .order_by(day)
    )
    return [tuple(r) for r in conn.execute(query).all()]
