"""The records database's outages answered as outages: 503 with ``Retry-After``, never 500.

Why a handler at the edge and not in each route: every route reads or writes the records, and
an outage surfaces wherever the first statement runs (a pooled connection's pre-ping, a query, a
commit). SQLAlchemy wraps the driver's connection errors as `OperationalError` /
`InterfaceError`, and a pool with no free connection in time raises its `TimeoutError`; psycopg's
own errors are caught too, for code that talks to the driver directly. The engine pre-pings its
connections and connects with a short timeout (`records.database.engine`), so the routes answer
again by themselves once the database is back; nothing here needs a restart.

The body is one line naming the cause; the exception's text (host, port, SQL) goes to the log only.
A serialisation failure, a deadlock or a cancelled statement is the database being busy, not
gone, and says so.
"""

from __future__ import annotations

import logging

import psycopg
import sqlalchemy.exc
from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

log = logging.getLogger(__name__)

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


def install_records_outage(app: FastAPI, retry_after_s: int) -> None:
    """Register the 503 answer of a records outage for every route of `app`."""
    from bayesian_fields_service.api.edge import problem  # edge installs this handler

    async def _records_outage(request: Request, exc: Exception) -> JSONResponse:
        log.warning("%s %s: records database: %s: %s", request.method, request.url.path,
                    type(exc).__name__, str(exc).splitlines()[0] if str(exc) else "")  # fmt: skip
        return problem(
            503,
            f"{cause(exc)}; retry in {retry_after_s} s (a submission with the same Idempotency-Key)",
            headers={"Retry-After": str(retry_after_s)},
        )

    for kind in OUTAGES:
        app.add_exception_handler(kind, _records_outage)
