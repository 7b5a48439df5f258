"""The service's records in PostgreSQL (issue 28): scenes, jobs, batches, idempotency keys, the
callback outbox and the usage ledger, as SQLAlchemy Core tables (`tables`) whose schema is
versioned by Alembic migrations (`migrations/`), applied by `bfields-service migrate` or at
start-up under one advisory lock (`database.migrate`), and readable as it stands in `schema.sql`.

The only package that issues SQL (issue 43; `tests/services/records/test_records_boundary.py`):
one module of statement functions per aggregate, each taking a `Connection` so that several
share one transaction (`jobs`, `keys`, `queue`, `batches`, `scenes`, `outbox`, `usage`,
`job_heartbeats`, `leases`), and the unit of work the domains open, `begin` / `connect`. The
rules (a job's merge, cancel-wins, a batch's status, the fair share) stay in the domains.

Why PostgreSQL: a fleet operation (submit, cancel or page a 5,000-job batch) must be a few
statements inside one transaction, not a loop of object-store round trips; a state change must
be one conditional UPDATE; and the records must survive losing Redis, which keeps only Celery's
broker and live progress. What is large (uploads, artifacts, results) stays in object storage.
"""

from __future__ import annotations

from contextlib import AbstractContextManager

from sqlalchemy import Connection, Engine


def begin(database: Engine) -> AbstractContextManager[Connection]:
    """The unit of work: one transaction on `database`, committed when the ``with`` body ends
    (rolled back on an exception). A domain opens it and hands its connection to the statement
    functions of this package (`jobs`, `queue`, `batches`, ...), so several of them commit
    together or not at all."""
    return database.begin()


def connect(database: Engine) -> AbstractContextManager[Connection]:
    """A connection for reads (autobegun, rolled back at the end of the ``with`` body)."""
    return database.connect()
