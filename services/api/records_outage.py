"""The records database's outages answered as outages: 503 with ``Retry-After``, never 500.

Why a handler at the edge and not in each route: every route reads or writes the records, and
an outage surfaces wherever the first statement runs (a pooled connection's pre-ping, a query, a
commit). SQLAlchemy wraps the driver's connection errors as `OperationalError` /
`InterfaceError`, and a pool with no free connection in time raises its `TimeoutError`; psycopg's
own errors are caught too, for code that talks to the driver directly. `api.edge` installs the
handler (`OUTAGES`, worded by `cause`). The engine pre-pings its
connections and connects with a short timeout (`records.database.engine`), so the routes answer
again by themselves once the database is back; nothing here needs a restart.

The body is one line naming the cause; the exception's text (host, port, SQL) goes to the log only.
A serialisation failure, a deadlock or a cancelled statement is the database being busy, not
gone, and says so.
"""

from __future__ import annotations

import psycopg
import sqlalchemy.exc

#: The exceptions that mean the records database did not answer (or not in time).
OUTAGES: tuple[type[Exception], ...] = (
    sqlalchemy.exc.OperationalError,
    sqlalchemy.exc.InterfaceError,
    sqlalchemy.exc.TimeoutError,
    psycopg.OperationalError,
    psycopg.InterfaceError,
)
_BUSY = (psycopg.errors.TransactionRollback, psycopg.errors.QueryCanceled)


def cause(exc: BaseException) -> str:
    """What the client is told: the database is busy (it answered, but not this time) or unreachable."""
    driver_error = getattr(exc, "orig", None) or exc
    if isinstance(exc, sqlalchemy.exc.TimeoutError) or isinstance(driver_error, _BUSY):
        return "the records database (PostgreSQL) is busy"
    return "the records database (PostgreSQL) is unreachable"
