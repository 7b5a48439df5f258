"""The statements over `scenes` rows: insert (or adopt), load (plain, locked, share-locked),
page, publish, mark deleting, purge, and the sweeper's reads.

Why the row lock is taken here but decided on in the domain: a scene's fate (ready, deleting, no
row) is ordered by its row lock (`scenes.store` says how the three racing requests meet); the
domain opens the unit of work, loads the row locked through these functions and decides.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import ARRAY, Connection, RowMapping, cast, delete, func, insert, select, update
from sqlalchemy.dialects.postgresql import insert as pg_insert

from bayesian_fields_service.records.tables import ID, scenes

#: The row state of a scene whose delete was acknowledged (reads as absent everywhere).
DELETING = "deleting"


def _any_of(scene_ids: Sequence[str]) -> Any:
    """``id = ANY(:ids)``: one bound array however many ids (a batch may name thousands)."""
    return scenes.c.id == func.any(cast(list(scene_ids), ARRAY(ID)))


def insert_row(conn: Connection, row: dict[str, Any]) -> None:
    """A new scene's row (its id is new: a clash is an error)."""
    conn.execute(insert(scenes).values(**row))


def insert_if_absent(conn: Connection, row: dict[str, Any]) -> bool:
    """The row unless one with its id exists; True when inserted."""
    statement = pg_insert(scenes).values(**row).on_conflict_do_nothing(index_elements=["id"])
    # RETURNING: psycopg reports no rowcount for this one
    return conn.execute(statement.returning(scenes.c.id)).first() is not None


def load(conn: Connection, tenant: str, scene_id: str, *, lock: bool = False) -> RowMapping | None:
    """The scene's row in any state, or None; `lock`: ``FOR UPDATE`` until the transaction ends."""
    query = select(scenes).where(scenes.c.tenant == tenant, scenes.c.id == scene_id)
    if lock:
        query = query.with_for_update()
    return conn.execute(query).mappings().first()


def share_lock(conn: Connection, tenant: str, scene_ids: Sequence[str]) -> dict[str, RowMapping]:
    """The rows of `scene_ids` that exist, held ``FOR SHARE`` until the transaction ends (in id
    order, so two transactions never lock them crosswise)."""
    query = select(scenes).where(scenes.c.tenant == tenant, _any_of(scene_ids)).order_by(scenes.c.id)
    return {r["id"]: r for r in conn.execute(query.with_for_update(read=True)).mappings()}


def page(conn: Connection, tenant: str, limit: int, before: str | None = None) -> list[RowMapping]:
    """Up to `limit` of the tenant's rows that are not deleting, newest first (descending id),
    with ids below `before` when given."""
    query = select(scenes).where(scenes.c.tenant == tenant, scenes.c.state != DELETING)
    if before is not None:
        query = query.where(scenes.c.id < before)
    return list(conn.execute(query.order_by(scenes.c.id.desc()).limit(limit)).mappings().all())


def set_ready(
    conn: Connection, tenant: str, scene_id: str, *, files: int, size: int, summary: dict[str, Any]
) -> RowMapping:
    """Turn the row ready with its files, bytes and summary and no pending uploads; the new row."""
    return (
        conn.execute(
            update(scenes)
            .where(scenes.c.tenant == tenant, scenes.c.id == scene_id)
            .values(state="ready", files=files, bytes=size, summary=summary, pending_uploads=[],
                    updated_at=datetime.now(UTC))
            .returning(*scenes.c)
        )
        .mappings()
        .one()
    )  # fmt: skip


def set_deleting(conn: Connection, tenant: str, scene_id: str) -> None:
    """Mark the row deleting."""
    conn.execute(
        update(scenes)
        .where(scenes.c.tenant == tenant, scenes.c.id == scene_id)
        .values(state=DELETING, updated_at=datetime.now(UTC))
    )


def purge(conn: Connection, tenant: str, scene_id: str) -> None:
    """Drop the row if it is deleting (a row in any other state stays)."""
    conn.execute(
        delete(scenes).where(scenes.c.tenant == tenant, scenes.c.id == scene_id, scenes.c.state == DELETING)
    )


def deleting(conn: Connection) -> list[tuple[str, str, list[dict[str, Any]]]]:
    """(tenant, id, pending uploads) of every deleting row, by id."""
    query = select(scenes.c.tenant, scenes.c.id, scenes.c.pending_uploads).where(scenes.c.state == DELETING)
    return [(r.tenant, r.id, list(r.pending_uploads)) for r in conn.execute(query.order_by(scenes.c.id))]


def pending_uploads(
    conn: Connection, tenant: str, scene_ids: Sequence[str]
) -> dict[str, list[dict[str, Any]]]:
    """The pending uploads each row among `scene_ids` lists (rows in any state; absent: no row)."""
    query = select(scenes.c.id, scenes.c.pending_uploads).where(scenes.c.tenant == tenant, _any_of(scene_ids))
    return {r.id: list(r.pending_uploads) for r in conn.execute(query)}
