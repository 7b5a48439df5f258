"""Connections to the records database, and the schema migration every process may start with.

Why an advisory lock around the migration: the API replicas, the control process and the
workers all start at once in a deployment, and each may run `migrate` at start-up; one
transaction-scoped `pg_advisory_xact_lock` makes the first apply the pending revisions while the
others wait and then find nothing to do. Never by hand: `bfields-service migrate` runs the same.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Engine, create_engine, text

MIGRATIONS = Path(__file__).resolve().parent / "migrations"
MIGRATION_LOCK = 0x62666965_6C647331  # "bfields1": the advisory lock key every migrator takes
"""The key of the advisory lock that serialises migrations (any fixed 64-bit integer)."""


@lru_cache(maxsize=8)
def engine(url: str) -> Engine:
    """One pooled engine per database URL per process (`postgresql+psycopg://...`)."""
    return create_engine(url, pool_pre_ping=True, pool_size=10, max_overflow=10, future=True)


def alembic_config() -> Config:
    """Alembic's configuration, built in code (no alembic.ini): the scripts live in this package."""
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    return config


def head_revision() -> str:
    """The newest revision of the scripts (what `migrate` brings a database to)."""
    head = ScriptDirectory.from_config(alembic_config()).get_current_head()
    assert head is not None, "no migration scripts"
    return head


def current_revision(url: str) -> str | None:
    """The revision a database is at (None: never migrated)."""
    with engine(url).connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()


def migrate(url: str, revision: str = "head") -> str | None:
    """Bring the database at `url` to `revision` under the migration lock; returns the revision
    it is at afterwards. Safe to call from every process at once (module docstring)."""
    config = alembic_config()
    with engine(url).begin() as conn:
        conn.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": MIGRATION_LOCK})
        config.attributes["connection"] = conn
        if revision.startswith("-") or revision == "base":
            command.downgrade(config, revision)
        else:
            command.upgrade(config, revision)
        return MigrationContext.configure(conn).get_current_revision()
