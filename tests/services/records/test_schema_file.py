"""`records/schema.sql`, the readable current schema, is what the metadata and the migrations'
trigger SQL make (no server needed), and a database migrated to head has exactly the functions
and triggers it lists (the tables and indexes are compared by `test_migrations`)."""

from __future__ import annotations

import re

from sqlalchemy import text

from bayesian_fields_service.records import schema
from bayesian_fields_service.records.database import engine, migrate


def drift(written: str) -> str | None:
    """Why `written` is not the schema file it should be (None: it is)."""
    if written == schema.render():
        return None
    return f"{schema.SCHEMA_FILE.name} is stale: rewrite it with `{schema.FIX_COMMAND}` and commit it"


def test_the_schema_file_is_what_the_metadata_and_the_triggers_make() -> None:
    problem = drift(schema.SCHEMA_FILE.read_text())
    assert problem is None, problem


def test_the_check_fails_on_a_stale_file() -> None:
    current = schema.SCHEMA_FILE.read_text()
    assert drift(current.replace("CREATE TABLE jobs", "CREATE TABLE jobz")) is not None
    assert "--write" in (drift(current + "-- a hand edit\n") or "")


def test_the_schema_file_holds_the_batch_counter_triggers() -> None:
    body = schema.SCHEMA_FILE.read_text()
    assert "CREATE TRIGGER bf_batch_counts_on_jobs AFTER UPDATE ON jobs" in body
    assert "CREATE FUNCTION bf_apply_batch_deltas(changes jsonb)" in body


def test_a_database_at_head_has_the_functions_and_triggers_the_file_lists(fresh_database: str) -> None:
    migrate(fresh_database)
    body = schema.SCHEMA_FILE.read_text()
    listed_functions = set(re.findall(r"CREATE FUNCTION (\w+)\(", body))
    listed_triggers = set(re.findall(r"CREATE TRIGGER (\w+) ", body))
    with engine(fresh_database).connect() as conn:
        functions = set(
            conn.execute(
                text(
                    "SELECT p.proname FROM pg_proc p JOIN pg_namespace n ON n.oid = p.pronamespace "
                    "WHERE n.nspname = current_schema()"
                )
            ).scalars()
        )
        triggers = set(conn.execute(text("SELECT tgname FROM pg_trigger WHERE NOT tgisinternal")).scalars())
    assert listed_functions and listed_functions == functions
    assert listed_triggers and listed_triggers == triggers
