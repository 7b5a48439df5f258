"""Writes of a job's progress that must land: retried while the records database is unreachable.

Why: a stage's end and a job's end are written once, by the worker that ran the stage. When that
write failed during a database outage, the row kept an earlier state while the stage's artifacts
were in the bucket, and nothing ever wrote it again (a job found stuck for good). These writes are
idempotent (a stage's end merges into the row, a terminal state is written once with its callback
and usage rows, keyed by event and entry ids), so repeating one until it lands, or a late
duplicate of it, changes nothing twice. The wait is bounded (`record_write_budget_s`); past it the
error propagates and recovery finishes the job from its row once the database answers
(`control.recovery`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import TypeVar

from sqlalchemy.exc import DBAPIError, InterfaceError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout

log = logging.getLogger(__name__)

T = TypeVar("T")

#: The first wait after a failed write, doubled after each, capped at `_MAX_WAIT_S`.
_FIRST_WAIT_S = 0.5
_MAX_WAIT_S = 8.0


def unreachable(exc: BaseException) -> bool:
    """Whether `exc` says the records database could not be reached (not a bad statement)."""
    if isinstance(exc, (OperationalError, InterfaceError, PoolTimeout)):
        return True
    return isinstance(exc, DBAPIError) and bool(exc.connection_invalidated)


def until_landed(write: Callable[[], T], *, budget_s: float, what: str) -> T:
    """`write()`, repeated with exponential backoff while the database is unreachable, for at
    most `budget_s` seconds; any other error, or the last one past the budget, propagates."""
    deadline = time.monotonic() + budget_s
    wait = _FIRST_WAIT_S
    while True:
        try:
            return write()
        except Exception as exc:
            if not unreachable(exc) or time.monotonic() + wait > deadline:
                raise
            log.warning("%s: the records database is unreachable (%s); again in %.1f s",
                        what, type(exc).__name__, wait)  # fmt: skip
            time.sleep(wait)
            wait = min(_MAX_WAIT_S, wait * 2)
