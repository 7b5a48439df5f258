"""`GET /metrics` holds no tenant data for anonymous callers (issue 41, item 7): it answers only
the metrics token (an API key does not open it), does not exist where no token is set and
anonymous access is not allowed, and labels series per tenant only where the operator turns that
on. Real uvicorn APIs on the service tests' database, Redis and S3 server."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.integration.fixtures.services import METRICS_TOKEN, ApiServer

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def waiting_jobs(api: ApiServer, stored_scene: dict) -> Iterator[list[str]]:
    """Jobs of tenant-a, more than the dispatcher sends ahead (so some wait), cancelled after."""
    with api.client("tenant-a") as client:
        ids = [
            client.post("/v1/jobs", json={"scene_id": stored_scene["id"], "tasks": [f"m{i}"]}).json()["id"]
            for i in range(4)
        ]
        yield ids
        for job_id in ids:
            client.delete(f"/v1/jobs/{job_id}")


def _other_api(svc_env: dict[str, str], keys: dict[str, str], log_dir: Path, **env: str) -> ApiServer:
    """An API beside the session's, on the same records, with other metrics settings."""
    settings = {k: v for k, v in svc_env.items() if k != "BFIELDS_METRICS_TOKEN"} | env
    return ApiServer(env=settings, log_dir=log_dir, keys=dict(keys), control=False).start()


def test_metrics_need_the_metrics_token_and_name_no_tenant_by_default(
    api: ApiServer, test_api_keys: dict[str, str], waiting_jobs: list[str]
) -> None:
    url = f"{api.base_url}/metrics"
    key = test_api_keys["tenant-a"]
    for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": f"Bearer {key}"},
                    {"X-API-Key": key}, {"Authorization": METRICS_TOKEN}):  # fmt: skip
        resp = httpx.get(url, headers=headers)
        assert resp.status_code == 401, (headers, resp.text)
        assert resp.headers["WWW-Authenticate"] == "Bearer" and "metrics token" in resp.json()["detail"]
        assert "tenant-a" not in resp.text and "bfields_" not in resp.text
    text = api.metrics()
    assert "bfields_jobs_active" in text and 'bfields_queue_depth{queue="gpu"}' in text
    assert "tenant=" not in text and "tenant-a" not in text and "tenant-b" not in text, text
    waiting = [line for line in text.splitlines() if line.startswith("bfields_jobs_waiting ")]
    assert len(waiting) == 1 and float(waiting[0].split()[1]) >= 0, waiting


def test_metrics_are_off_without_a_token_and_per_tenant_only_when_turned_on(
    svc_env: dict[str, str], test_api_keys: dict[str, str], tmp_path: Path, waiting_jobs: list[str]
) -> None:
    off = _other_api(svc_env, test_api_keys, tmp_path / "off")
    try:
        resp = httpx.get(f"{off.base_url}/metrics", headers={"Authorization": f"Bearer {METRICS_TOKEN}"})
        assert resp.status_code == 404 and "BFIELDS_METRICS_TOKEN" in resp.json()["detail"], resp.text
    finally:
        off.stop()
    per_tenant = _other_api(
        svc_env, test_api_keys, tmp_path / "per-tenant",
        BFIELDS_METRICS_ANONYMOUS="true", BFIELDS_METRICS_PER_TENANT="true",
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 20
        while True:  # the control process dispatches some of the jobs; the rest wait
            resp = httpx.get(f"{per_tenant.base_url}/metrics")  # anonymous: allowed on this one
            assert resp.status_code == 200, resp.text
            if 'bfields_jobs_waiting{tenant="tenant-a"}' in resp.text:
                break
            assert time.monotonic() < deadline, resp.text
            time.sleep(0.5)
    finally:
        per_tenant.stop()
