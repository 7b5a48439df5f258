"""Integration fixtures: real Redis, a real S3 server (rclone), real Celery workers and a real
uvicorn API, all as subprocesses (see `fixtures/pytest_fixtures.py` for names and usage).

When a test fails, the tail of every service process's log is attached to its report.
"""

from __future__ import annotations

import pytest

from .fixtures.pytest_fixtures import (  # noqa: F401 - fixtures are found by name
    api_server,
    celery_workers,
    private_redis,
    redis_url,
    s3_server,
    s3_store,
    service_env,
    test_api_keys,
)
from .fixtures.report import attach_process_logs

pytestmark = pytest.mark.integration


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]):  # noqa: ANN201
    yield from attach_process_logs(item, call)
