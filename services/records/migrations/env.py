"""Alembic's entry point: runs the migrations on the connection `database.migrate` hands over
(`config.attributes["connection"]`), inside its advisory lock and transaction. No alembic.ini:
the configuration is built in code from the service's settings."""

from __future__ import annotations

from alembic import context

from bayesian_fields_service.records.tables import metadata

connection = context.config.attributes.get("connection")
if connection is None:  # pragma: no cover - only `database.migrate` runs these migrations
    raise RuntimeError("run migrations through bayesian_fields_service.records.database.migrate")
context.configure(connection=connection, target_metadata=metadata, compare_type=True)
with context.begin_transaction():
    context.run_migrations()
