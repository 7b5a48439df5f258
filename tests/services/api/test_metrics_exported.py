"""`GET /metrics` exports every family the shipped dashboard and alert rules read, and still answers
with PostgreSQL or Redis down (issue 44, item 2): the outage is its ``bfields_*_up`` gauge at 0,
the families that source gives are left out, and the rest are still there.

A real uvicorn API on a PostgreSQL server and a redis-server of this test's own (stopping the
shared ones would break every other test), the session's S3 server. The workers' Redis histograms
are written through the functions the workers call (`live.metrics`), so every histogram family has
a series without running a fleet; bench/observability_fleet.py does the same with real workers and a
real Prometheus."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import redis

from bayesian_fields_core.job.stage_table import STAGES
from bayesian_fields_service.live import metrics as live_metrics
from tests.integration.fixtures.private_postgres import PrivatePostgres
from tests.integration.fixtures.redis_server import RedisServer
from tests.integration.fixtures.services import ApiServer
from tests.support.observability import expressions, scraped_names, unexported

pytestmark = [pytest.mark.integration, pytest.mark.timeout(240)]


@pytest.fixture
def own_api(
    private_pg: PrivatePostgres,
    private_redis: RedisServer,
    svc_env: dict[str, str],
    test_api_keys: dict[str, str],
    tmp_path: Path,
) -> Iterator[ApiServer]:
    """The service tests' API on this test's PostgreSQL and Redis (no control process: its leader
    gauge reads 0)."""
    env = {**svc_env, "BFIELDS_DATABASE_URL": private_pg.url(), "BFIELDS_REDIS_URL": private_redis.url(),
           "BFIELDS_API_BULK_LANE": "false"}  # fmt: skip
    server = ApiServer(env=env, log_dir=tmp_path, keys=dict(test_api_keys), control=False).start()
    yield server
    server.stop()


def _observe_every_histogram(client: redis.Redis) -> None:
    for stage in STAGES:
        live_metrics.observe_stage(client, stage, 2.5)
        live_metrics.observe_stage_queue_wait(client, stage, 0.3)
        live_metrics.observe_stage_resources(client, stage, cpu_s=2.0, gpu_s=0.0, gpu_peak_bytes=0)
    live_metrics.observe_job(client, "succeeded", 9.0)
    live_metrics.observe_queue_wait(client, "tenant-a", 0.2)


def _values(text: str) -> dict[str, float]:
    """{series as written: value} of an exposition."""
    out = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            series, _, value = line.rpartition(" ")
            out[series] = float(value)
    return out


def test_every_dashboard_and_alert_metric_is_exported_and_outages_read_as_zero(
    own_api: ApiServer, private_pg: PrivatePostgres, private_redis: RedisServer
) -> None:
    _observe_every_histogram(redis.Redis.from_url(private_redis.url()))
    text = own_api.metrics()
    values = _values(text)
    assert unexported(expressions(), scraped_names(text)) == {}
    assert values["bfields_database_up"] == 1 and values["bfields_redis_up"] == 1
    assert values["bfields_control_leader"] == 0  # no control process on this database
    assert values['bfields_jobs{state="queued"}'] == 0 == values["bfields_jobs_stalled"]
    assert (
        values["bfields_callback_outbox_depth"] == 0 == values["bfields_callback_outbox_oldest_age_seconds"]
    )
    assert values['bfields_stage_queue_wait_seconds_bucket{le="0.5",stage="perceive"}'] == 1
    assert values['bfields_stage_cpu_seconds_total{stage="fuse"}'] == 2.0
    assert values['bfields_stage_gpu_seconds_total{stage="fuse"}'] == 0.0  # a CPU worker's stage
    assert values['bfields_stage_gpu_memory_peak_bytes_bucket{le="0",stage="fuse"}'] == 1

    private_redis.stop()
    t0 = time.monotonic()
    values = _values(own_api.metrics())  # 200 (raises otherwise)
    assert time.monotonic() - t0 < 15
    assert values["bfields_redis_up"] == 0 and values["bfields_database_up"] == 1
    assert "bfields_jobs_active" in values and 'bfields_jobs{state="running"}' in values
    assert not any(s.startswith(("bfields_queue_depth", "bfields_stage_")) for s in values), values

    private_redis.start()
    private_pg.stop()
    t0 = time.monotonic()
    values = _values(own_api.metrics())
    assert time.monotonic() - t0 < 15
    assert values["bfields_database_up"] == 0 and values["bfields_redis_up"] == 1
    assert not any(
        s.startswith(("bfields_jobs", "bfields_control_leader", "bfields_callback")) for s in values
    )
    assert 'bfields_stage_seconds_count{stage="perceive"}' in values  # Redis's families are still there
