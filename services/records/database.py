"""Connections to the records database, and the schema migration every process may start with.

Why an advisory lock around the migration: the API replicas, the control process and the
workers all start at once in a deployment, and each may run `migrate` at start-up; one
transaction-scoped `pg_advisory_xact_lock` makes the first apply the pending revisions while the
others wait and then find nothing to do. Never by hand: `bfields-service migrate` runs the same.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Engine, create_engine, text
from sqlalchemy.engine import make_url

from bayesian_fields_service.observability import tracing

MIGRATIONS = Path(__file__).resolve().parent / "migrations"
MIGRATION_LOCK = 0x62666965_6C647331  # "bfields1": the advisory lock key every migrator takes
"""The key of the advisory lock that serialises migrations (any fixed 64-bit integer)."""


#: Seconds a new connection may take (libpq's ``connect_timeout``; a ``?connect_timeout=N`` in
#: the URL wins). Short, so an unreachable database is an error in seconds (the API answers 503)
#: rather than a request hanging on the operating system's TCP timeout.
CONNECT_TIMEOUT_S = 3


@lru_cache(maxsize=8)
def engine(url: str) -> Engine:
    """One pooled engine per database URL per process (`postgresql+psycopg://...`).

    Every checkout pre-pings its connection, so connections a database restart broke are
    replaced on their next use, and the process recovers by itself once the database is back."""
    connect_args = {} if "connect_timeout" in make_url(url).query else {"connect_timeout": CONNECT_TIMEOUT_S}
    created = create_engine(
        url, pool_pre_ping=True, pool_size=10, max_overflow=10, connect_args=connect_args, future=True
    )
    _ENGINES.append(created)
    tracing.instrument_engine(created)  # its statements as spans when tracing is on
    return created


def _forget_engines_after_fork() -> None:
    """A forked child (a prefork Celery worker) must not use its parent's pooled connections:
    drop them without closing (they are the parent's) and let the child build its own."""
    for cached in list(_ENGINES):
        cached.dispose(close=False)
    _ENGINES.clear()
    engine.cache_clear()


_ENGINES: list[Engine] = []
os.register_at_fork(after_in_child=_forget_engines_after_fork)


def dispose_all() -> None:
    """Close every engine of this process (tests dropping their database; process shutdown)."""
    for cached in list(_ENGINES):
        cached.dispose()
    _ENGINES.clear()
    engine.cache_clear()


_MIGRATED: set[str] = set()


def open_records(url: str, *, migrate_first: bool) -> Engine:
    """The engine a service process uses, after bringing the schema to head once per process when
    `migrate_first` (the `migrate_on_start` setting; see `migrate` for why that is safe)."""
    if migrate_first and url not in _MIGRATED:
        migrate(url)
        _MIGRATED.add(url)
    return engine(url)


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


def ping(database: Engine) -> None:
    """``SELECT 1`` on a pooled connection (pre-pinged) or a new one within the connect timeout:
    the readiness probes' check; raises whatever reaching the database raised."""
    with database.connect() as conn:
        conn.execute(text("SELECT 1"))


def create_database(url: str) -> bool:
    """Create the database `url` names when it does not exist (connecting to the server's
    `postgres` database, outside a transaction: CREATE DATABASE cannot run inside one); True when
    created."""
    target = make_url(url)
    name = target.database
    admin = target.set(database="postgres")
    eng = engine(admin.render_as_string(hide_password=False)).execution_options(isolation_level="AUTOCOMMIT")
    with eng.connect() as conn:
        if conn.execute(text("SELECT 1 FROM pg_database WHERE datname = :n"), {"n": name}).first():
            return False
        conn.execute(text(f'CREATE DATABASE "{name}"'))
        return True
