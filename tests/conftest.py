"""What every test directory shares, found by pytest through this root conftest (no star imports).

The shared fixtures live in plain modules, registered here once as plugins so that a fixture has
one definition and any test directory can ask for it by name:

- `tests.integration.fixtures.pytest_fixtures`: the real processes (`redis_url`, `private_redis`,
  `s3_server`, `s3_store`, `test_api_keys`, `service_env`, `celery_workers`, `api_server`);
- `tests.services.support.stack_fixtures`: the service-test stack on top of them (`svc_env`, `api`,
  `client_a`, `client_b`, `scene_dir`, `stored_scene`, `model_profile`, `worker_env`, `workers`,
  `private_stacks`), used by tests/services and the API fuzz tests;
- `tests.support.browser`: `browser`, headless chromium for tests/services/api/ui and tests/core/viewer.

A fixture used by one directory only stays in that directory's conftest. Every test has a default
timeout (`timeout` in pyproject.toml's `[tool.pytest.ini_options]`); a test that legitimately runs
longer says so with `@pytest.mark.timeout(N)`.
"""

from __future__ import annotations

from collections.abc import Generator
from pathlib import Path

import pytest

from tests.integration.fixtures.report import attach_process_logs

pytest_plugins = [
    "tests.integration.fixtures.pytest_fixtures",
    "tests.services.support.stack_fixtures",
    "tests.support.browser",
]


#: The fixtures that start or claim a real server (Redis, the S3 server, PostgreSQL); every other
#: live fixture (`service_env`, `api`, `celery_workers`, `private_stacks`, ...) stands on one of them.
SERVER_FIXTURES = frozenset({"redis_url", "private_redis", "s3_server", "records_db", "fresh_database"})


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test that needs a real server is an integration test whether or not its module says so:
    the mark follows the fixtures it requests (directly or through others), so the inner loop
    (`-m "not slow and not integration"`) never waits on a server."""
    for item in items:
        if SERVER_FIXTURES.intersection(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.integration)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Generator[None, None, None]:
    """A failed test's report carries the log tails of the service processes it ran against."""
    yield from attach_process_logs(item, call)


@pytest.fixture
def tmp_home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """HOME and the caches of HOME-writing model libraries (onnxruntime, ultralytics settings, HF)
    inside this test's tmp folder, with the HF hub offline: a test never writes to the real home
    or reaches for the network. Returns the HOME folder."""
    home = tmp_path / "home"
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.setenv("YOLO_CONFIG_DIR", str(tmp_path / "yolo"))
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    return home
