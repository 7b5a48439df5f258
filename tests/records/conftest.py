"""A PostgreSQL database of this test run's own, created on the server the machine runs
(127.0.0.1:5432, trust auth; `BFIELDS_TEST_POSTGRES` overrides) and dropped at the end, so runs
never see each other's rows. Each test that needs an empty schema gets a fresh database."""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator

import pytest
from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url

SERVER = os.environ.get("BFIELDS_TEST_POSTGRES", "postgresql+psycopg://postgres@127.0.0.1:5432/postgres")


def _admin():
    return create_engine(SERVER, isolation_level="AUTOCOMMIT", pool_pre_ping=True)


@pytest.fixture
def fresh_database() -> Iterator[str]:
    """The URL of a new, empty database, dropped (connections and all) after the test."""
    name = f"bf_test_{os.getpid()}_{secrets.token_hex(4)}"
    admin = _admin()
    with admin.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}"'))
    url = make_url(SERVER).set(database=name).render_as_string(hide_password=False)
    try:
        yield url
    finally:
        from bayesian_fields_service.records.database import engine

        engine(url).dispose()
        engine.cache_clear()
        with admin.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()
