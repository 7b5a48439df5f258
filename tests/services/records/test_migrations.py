"""The records schema through its migrations, on a real PostgreSQL: applied from empty, equal
to `records.tables`, reversible, safe when every process of a deployment migrates at once, and
run by `bfields-service migrate`."""

from __future__ import annotations

import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import inspect

from bayesian_fields_service.records.database import current_revision, engine, head_revision, migrate
from bayesian_fields_service.records.tables import metadata

TABLES = {
    "scenes",
    "batches",
    "batch_jobs",
    "jobs",
    "idempotency_keys",
    "callback_outbox",
    "usage_ledger",
    "control_leases",
    "answers",
}


def test_migrating_an_empty_database_creates_the_tables_of_records_tables(fresh_database: str) -> None:
    assert current_revision(fresh_database) is None
    assert migrate(fresh_database) == head_revision()
    with engine(fresh_database).connect() as conn:
        assert set(inspect(conn).get_table_names()) == TABLES | {"alembic_version"}
        diff = compare_metadata(MigrationContext.configure(conn, opts={"compare_type": True}), metadata)
    assert diff == [], f"the migrations and records/tables.py disagree: {diff}"


def test_the_indexes_the_api_pages_and_counts_by_exist(fresh_database: str) -> None:
    migrate(fresh_database)
    with engine(fresh_database).connect() as conn:
        indexes = {ix["name"]: ix for ix in inspect(conn).get_indexes("jobs")}
    assert indexes["ix_jobs_tenant_created_at_id"]["column_names"] == ["tenant", "created_at", "id"]
    assert indexes["ix_jobs_batch_id_id"]["column_names"] == ["batch_id", "id"]
    waiting = indexes["ix_jobs_waiting"]
    assert waiting["column_names"] == ["tenant", "priority", "created_at", "id"]
    assert "dispatched_at IS NULL" in waiting["dialect_options"]["postgresql_where"]
    with engine(fresh_database).connect() as conn:  # the fleet search's: a row per job and task
        latest = {ix["name"]: ix for ix in inspect(conn).get_indexes("answers")}["ix_answers_latest"]
    assert latest["column_names"] == ["tenant", "task", "scene_id", "finished_at", "job_id"]
    assert "rank <= 1" in latest["dialect_options"]["postgresql_where"]
    assert latest["dialect_options"]["postgresql_include"] == ["task_index", "rank", "found", "probability"]


def test_migrations_go_down_to_base_and_up_again(fresh_database: str) -> None:
    migrate(fresh_database)
    assert migrate(fresh_database, "base") is None
    with engine(fresh_database).connect() as conn:
        assert set(inspect(conn).get_table_names()) == {"alembic_version"}
    assert migrate(fresh_database) == head_revision()


def test_every_process_migrating_at_once_is_safe(fresh_database: str) -> None:
    """Six starting processes race to migrate the same empty database: without the advisory lock
    two of them would CREATE TABLE at once and one would fail on the duplicate."""
    with ThreadPoolExecutor(6) as pool:
        results = list(pool.map(lambda _: migrate(fresh_database), range(6)))
    assert results == [head_revision()] * 6


def test_the_migrate_command_applies_and_reports(fresh_database: str) -> None:
    bin_dir = Path(sys.executable).parent
    env = {**os.environ, "BFIELDS_DATABASE_URL": fresh_database}
    out = subprocess.run(
        [str(bin_dir / "bfields-service"), "migrate"], env=env, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert f"at revision {head_revision()}" in out.stdout
    out = subprocess.run(
        [str(bin_dir / "bfields-service"), "db-revision"], env=env, capture_output=True, text=True, timeout=60
    )
    assert out.stdout.split()[0] == head_revision()


@pytest.mark.slow
def test_the_migrate_command_names_an_unreachable_database_in_one_line() -> None:
    bin_dir = Path(sys.executable).parent
    env = {**os.environ, "BFIELDS_DATABASE_URL": "postgresql+psycopg://nobody:secret@127.0.0.1:1/none"}
    out = subprocess.run(
        [str(bin_dir / "bfields-service"), "migrate"], env=env, capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert (
        len(lines) == 1
        and "cannot reach the records database" in lines[0]
        and "BFIELDS_DATABASE_URL" in lines[0]
    )
    assert "secret" not in out.stderr


def test_the_migrate_command_creates_the_database_it_names_when_asked() -> None:
    """The no-Docker recipe (docs/service/index.md) creates its own database this way instead of
    writing into whatever database answers on the server."""
    from sqlalchemy.engine import make_url

    from tests.integration.fixtures.postgres import PREFIX, SERVER, drop_database

    url = make_url(SERVER).set(database=f"{PREFIX}{os.getpid()}_cli_{os.urandom(4).hex()}")
    shown = url.render_as_string(hide_password=False)
    bin_dir = Path(sys.executable).parent
    env = {**os.environ, "BFIELDS_DATABASE_URL": shown}
    argv = [str(bin_dir / "bfields-service"), "migrate", "--create-database"]
    try:
        first = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=120)
        assert first.returncode == 0, first.stderr
        assert f"created database {url.database}" in first.stdout
        assert f"at revision {head_revision()}" in first.stdout
        assert current_revision(shown) == head_revision()
        again = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=120)
        assert again.returncode == 0 and "created database" not in again.stdout, again.stdout + again.stderr
    finally:
        drop_database(shown)
