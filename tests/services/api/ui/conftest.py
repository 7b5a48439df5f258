"""The /ui tests run the real stack (Redis, rclone S3, uvicorn API, Celery workers on both queues)
from the integration fixtures, and drive the page in headless chromium (`browser.py`); both are
registered for every directory by the root conftest."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.integration.fixtures.services import WorkerPool


@pytest.fixture(scope="module")
def ui_workers(celery_workers: WorkerPool) -> Iterator[WorkerPool]:
    """One worker per queue (solo pool) with the bundled default model profile."""
    started = [celery_workers.start("gpu"), celery_workers.start("cpu")]
    yield celery_workers
    for worker in started:
        if worker.alive:
            worker.stop()
