"""An API process of a test module's own, with its own Redis and S3 server and two tenants
(tenant-a, tenant-b), for the tests that set the API's limits to values no other test may share
(the tenant gate's bounds, the request rate). No control process and no bulk lane: these tests
look at the API's edge only."""

from __future__ import annotations

import secrets
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

from tests.integration.fixtures.redis_server import RedisServer
from tests.integration.fixtures.s3_server import S3Server
from tests.integration.fixtures.services import ApiServer, build_service_env


@contextmanager
def lone_api(tmp: Path, settings: Mapping[str, str]) -> Iterator[ApiServer]:
    """A started API with `settings` (BFIELDS_* values) on top of the test environment."""
    redis_server = RedisServer(tmp / "redis").start()
    s3 = S3Server(tmp / "s3").start()
    keys = {t: f"key-{t}-" + secrets.token_urlsafe(12) for t in ("tenant-a", "tenant-b")}
    extra = {"BFIELDS_API_BULK_LANE": "false", **settings}
    try:
        env = build_service_env(tmp / "env", redis_server.url(), s3.env(), keys, extra)
        api = ApiServer(env=env, log_dir=tmp / "api", keys=keys, control=False).start()
        try:
            yield api
        finally:
            api.stop()
    finally:
        s3.stop()
        redis_server.stop()
