"""A PostgreSQL database of this test's own (`tests.integration.fixtures.postgres`): each test
that needs an empty schema gets a fresh database, dropped after it."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from sqlalchemy import Engine

from tests.integration.fixtures.postgres import create_database, drop_database, records_database


@pytest.fixture
def fresh_database() -> Iterator[str]:
    """The URL of a new, empty database, dropped (connections and all) after the test."""
    url = create_database()
    try:
        yield url
    finally:
        drop_database(url)


@pytest.fixture
def records_db() -> Iterator[Engine]:
    """An engine on a database of this test's own at the newest schema, dropped after it."""
    with records_database() as db:
        yield db
