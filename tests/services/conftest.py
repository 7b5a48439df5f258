"""Service tests run against real processes: the integration fixtures (Redis, rclone S3, Celery
workers, uvicorn) plus an API started with the small limits below, so the limit checks are cheap to
exercise. The fixtures are in `stack_fixtures.py` (registered by the root conftest, so the API
fuzz tests share them); the limits and the upload form stay here, where the tests import them.

A PostgreSQL database of a test's own (`tests.integration.fixtures.postgres`) is here too: the
records tests (tests/services/records) and the tests of the common, webhooks and control modules that keep
their rows there (scenes, usage, the callback outbox, the scene import) ask for one; each test
that needs an empty schema gets a fresh database, dropped after it."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import Engine

from tests.integration.fixtures.postgres import create_database, drop_database, records_database
from tests.integration.fixtures.private_postgres import PrivatePostgres, postgres_bin
from tests.services.support.service_hooks import PLUGIN_ENV

#: Limits of the test API, small enough to trip with tiny uploads.
MAX_UPLOAD = 2_000_000
MAX_EXPANDED = 4_000_000
MAX_MEMBERS = 100

SERVICE_ENV = {
    "BFIELDS_MAX_UPLOAD_BYTES": str(MAX_UPLOAD),
    "BFIELDS_MAX_ARCHIVE_UNCOMPRESSED_BYTES": str(MAX_EXPANDED),
    "BFIELDS_MAX_ARCHIVE_MEMBERS": str(MAX_MEMBERS),
    "BFIELDS_MAX_ACTIVE_JOBS_PER_TENANT": "100",
    # fast crash recovery: a dead worker's stage lock expires after 6 s, scans every 2 s
    "BFIELDS_STAGE_LOCK_TTL_S": "6",
    "BFIELDS_RECOVERY_INTERVAL_S": "2",
    "BFIELDS_RECOVERY_GRACE_S": "3",
    # Below the defaults (256 / 200) so the tests prove the configured limits are the ones applied.
    "BFIELDS_MAX_TASKS": "20",
    "BFIELDS_MAX_TASK_CHARS": "60",
    # Below the default (1,000) so a batch past the bound of GET /v1/batches/{id}?jobs=true is small.
    "BFIELDS_BATCH_JOBS_INLINE_MAX": "50",
    # The tests' plugin on the hook points: a race test holds a scene route or a stage at a named
    # pause (inert unless a test arms one); a worker logs its encoder calls when asked.
    **PLUGIN_ENV,
}


def scene_form(folder: Path, *, images_zip: bytes | None = None) -> list[tuple[str, tuple[str, bytes]]]:
    """The multipart form of a scene folder: images as files, or the given zip."""
    files = [
        ("splat", ("splat.ply", (folder / "splat.ply").read_bytes())),
        ("cameras", ("transforms.json", (folder / "transforms.json").read_bytes())),
    ]
    if images_zip is not None:
        files.append(("images", ("images.zip", images_zip)))
    else:
        files += [("images", (p.name, p.read_bytes())) for p in sorted((folder / "images").iterdir())]
    return files


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


@pytest.fixture
def private_pg() -> Iterator[PrivatePostgres]:
    """A PostgreSQL server of the test's own, which it may stop and start (an outage must never
    stop the shared server); stopped and deleted afterwards."""
    if postgres_bin() is None:
        pytest.skip("no PostgreSQL binaries under /usr/lib/postgresql/*/bin (Debian package postgresql)")
    server = PrivatePostgres().start()
    yield server
    server.remove()
