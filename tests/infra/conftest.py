"""Infra tests reuse the integration fixtures (real rclone S3 server, real redis-server)."""

from __future__ import annotations

import pytest

from tests.integration.fixtures.pytest_fixtures import (  # noqa: F401 - fixtures are found by name
    private_redis,
    redis_url,
    s3_server,
    s3_store,
    service_env,
    test_api_keys,
)
from tests.integration.fixtures.report import attach_process_logs


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]):  # noqa: ANN201
    yield from attach_process_logs(item, call)
