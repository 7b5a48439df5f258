"""The service's records in PostgreSQL (issue 28): scenes, jobs, batches, idempotency keys, the
callback outbox and the usage ledger, as SQLAlchemy Core tables (`tables`) whose schema is
versioned by Alembic migrations (`migrations/`), applied by `bfields-service migrate` or at
start-up under one advisory lock (`database.migrate`).

Why PostgreSQL: a fleet operation (submit, cancel or page a 5,000-job batch) must be a few
statements inside one transaction, not a loop of object-store round trips; a state change must
be one conditional UPDATE; and the records must survive losing Redis, which keeps only Celery's
broker and live progress. What is large (uploads, artifacts, results) stays in object storage.
"""
