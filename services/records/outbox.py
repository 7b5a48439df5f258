"""The statements over `callback_outbox` rows: put an event in, list what is due, claim one,
read an open one, and settle an attempt (delivered, rescheduled or dropped).

Why here: an event row is inserted in the transaction of the state change that causes it, and
each move of a row afterwards is one conditional UPDATE that changes only an *open* row (neither
delivered nor dropped), so a sender that lost a race changes nothing. The delivery rules
(backoff, the attempts bound, signing) stay in `webhooks.callbacks`.
"""

from __future__ import annotations

from datetime import timedelta
from typing import Any

from sqlalchemy import Connection, RowMapping, and_, func, select, update
from sqlalchemy.dialects.postgresql import insert as pg_insert

from bayesian_fields_service.records.tables import callback_outbox

_OPEN = and_(callback_outbox.c.delivered_at.is_(None), callback_outbox.c.dropped_at.is_(None))


def enqueue(conn: Connection, tenant: str, url: str, event_id: str, event: dict[str, Any]) -> bool:
    """One event row (False when an event of that id is already there)."""
    statement = (
        pg_insert(callback_outbox)
        .values(tenant=tenant, url=url, event_id=event_id, event=event)
        .on_conflict_do_nothing(index_elements=[callback_outbox.c.event_id])
    )
    return bool(conn.execute(statement).rowcount)


def due(conn: Connection, offset: int, limit: int) -> list[tuple[int, str]]:
    """(row id, url) of open events whose next attempt is due, oldest due first."""
    rows = conn.execute(
        select(callback_outbox.c.id, callback_outbox.c.url)
        .where(_OPEN, callback_outbox.c.next_attempt_at <= func.now())
        .order_by(callback_outbox.c.next_attempt_at, callback_outbox.c.id)
        .offset(offset)
        .limit(limit)
    )
    return [(r.id, r.url) for r in rows]


def claim(conn: Connection, row_id: int, lease_s: float) -> bool:
    """Move a due open row's next attempt `lease_s` ahead; False when it is no longer due or open
    (another sender claimed or settled it)."""
    claimed = conn.execute(
        update(callback_outbox)
        .where(callback_outbox.c.id == row_id, _OPEN, callback_outbox.c.next_attempt_at <= func.now())
        .values(next_attempt_at=func.now() + timedelta(seconds=lease_s))
    )
    return bool(claimed.rowcount)


def load_open(conn: Connection, row_id: int) -> RowMapping | None:
    """The row while it is open, else None."""
    return (
        conn.execute(select(callback_outbox).where(callback_outbox.c.id == row_id, _OPEN)).mappings().first()
    )


def _settle(conn: Connection, row_id: int, values: dict[str, Any]) -> bool:
    changed = conn.execute(
        update(callback_outbox).where(callback_outbox.c.id == row_id, _OPEN).values(**values)
    )
    return bool(changed.rowcount)


def mark_delivered(conn: Connection, row_id: int, attempts: int) -> bool:
    """The open row delivered now after `attempts` attempts; False when it was not open."""
    return _settle(conn, row_id, {"delivered_at": func.now(), "attempts": attempts})


def mark_dropped(conn: Connection, row_id: int, attempts: int, error: str) -> bool:
    """The open row dropped now after `attempts` attempts, the last one's `error` kept."""
    return _settle(conn, row_id, {"dropped_at": func.now(), "attempts": attempts, "last_error": error})


def reschedule(conn: Connection, row_id: int, attempts: int, error: str, delay_s: float) -> bool:
    """The open row's next attempt `delay_s` from now, after `attempts` attempts."""
    return _settle(conn, row_id, {"attempts": attempts, "last_error": error,
                                  "next_attempt_at": func.now() + timedelta(seconds=delay_s)})  # fmt: skip
