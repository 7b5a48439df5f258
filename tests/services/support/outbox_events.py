"""Events put in a callback outbox by hand, and waiting on them: the delivery tests' helpers.

Events go into the outbox exactly as a finished job puts them there (`callbacks.enqueue`), so the
real sender (the control process) delivers them as it would a job's."""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable
from typing import Any

from sqlalchemy import Engine, select

from bayesian_fields_service.records.tables import callback_outbox
from bayesian_fields_service.webhooks import callbacks


def wait_for(check: Callable[[], bool], timeout_s: float, what: str) -> None:
    """Return once `check()` holds; AssertionError naming `what` after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if check():
            return
        time.sleep(0.02)
    raise AssertionError(f"not within {timeout_s} s: {what}")


def enqueue(outbox: Engine, url: str, kind: str, **fields: Any) -> str:
    """A ``test.<kind>`` event for `url` (with `fields` in its body) in the outbox; its event id."""
    event_id = f"test:{kind}:{uuid.uuid4().hex[:12]}"
    with outbox.begin() as conn:
        assert callbacks.enqueue(conn, "t", url, {"event_id": event_id, "type": f"test.{kind}", **fields})
    return event_id


def dropped(outbox: Engine) -> dict[str, dict]:
    """The dropped rows, by event id."""
    with outbox.connect() as conn:
        rows = conn.execute(
            select(callback_outbox).where(callback_outbox.c.dropped_at.is_not(None))
        ).mappings()
        return {r["event_id"]: dict(r) for r in rows}


def pending(outbox: Engine, event_ids: list[str]) -> list[str]:
    """Those of `event_ids` neither delivered nor dropped yet."""
    with outbox.connect() as conn:
        rows = conn.execute(
            select(callback_outbox.c.event_id).where(
                callback_outbox.c.event_id.in_(event_ids),
                callback_outbox.c.delivered_at.is_(None),
                callback_outbox.c.dropped_at.is_(None),
            )
        )
        return [r.event_id for r in rows]


def delivered(outbox: Engine, event_id: str) -> dict | None:
    """The event's row once delivered, else None."""
    with outbox.connect() as conn:
        row = (
            conn.execute(
                select(callback_outbox).where(
                    callback_outbox.c.event_id == event_id, callback_outbox.c.delivered_at.is_not(None)
                )
            )
            .mappings()
            .first()
        )
        return dict(row) if row is not None else None
