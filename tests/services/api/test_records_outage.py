"""The records database's outage answered as an outage (issue 41, item 3, the API's part): with
PostgreSQL stopped, every route that reads or writes records answers 503 + Retry-After with a
one-line body naming the database, `/readyz` says 503 naming `postgresql`, and once the server is
back the same API process answers normally again within seconds (pre-pinged pool, no restart).

The server is a private one started by this test (`PrivatePostgres`): stopping the shared one on
5432 would break every other test running against it. Real uvicorn API, real Redis and S3."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.integration.fixtures.private_postgres import PrivatePostgres
from tests.integration.fixtures.services import ApiServer
from tests.services.conftest import scene_form
from tests.services.support.problems import assert_problem

pytestmark = [pytest.mark.integration, pytest.mark.timeout(240)]

RETRY_AFTER = "5"  # BFIELDS_RETRY_AFTER_S, the default


@pytest.fixture
def outage_api(
    private_pg: PrivatePostgres, svc_env: dict[str, str], test_api_keys: dict[str, str], tmp_path: Path
) -> Iterator[ApiServer]:
    """The service tests' API on the private server (no control process: nothing to dispatch)."""
    env = {**svc_env, "BFIELDS_DATABASE_URL": private_pg.url(), "BFIELDS_API_BULK_LANE": "false"}
    server = ApiServer(env=env, log_dir=tmp_path, keys=dict(test_api_keys), control=False).start()
    yield server
    server.stop()


def _requests(client: httpx.Client, job_id: str, scene_id: str) -> dict[str, httpx.Response]:
    return {
        "GET job": client.get(f"/v1/jobs/{job_id}"),
        "GET jobs": client.get("/v1/jobs"),
        "GET usage": client.get("/v1/usage"),
        "GET scene": client.get(f"/v1/scenes/{scene_id}"),
        "POST job": client.post("/v1/jobs", json={"scene_id": scene_id, "tasks": ["blob"]}),
        "POST batch": client.post("/v1/batches", json={"scene_ids": [scene_id], "task_lists": [["blob"]]}),
    }


def test_a_stopped_database_is_a_503_with_retry_after_and_the_api_recovers_by_itself(
    private_pg: PrivatePostgres, outage_api: ApiServer, scene_dir: Path
) -> None:
    with outage_api.client("tenant-a") as client:
        scene = client.post("/v1/scenes", files=scene_form(scene_dir), data={"name": "outage"})
        assert scene.status_code == 201, scene.text
        scene_id = scene.json()["id"]
        job = client.post("/v1/jobs", json={"scene_id": scene_id, "tasks": ["blob"]})
        assert job.status_code == 202, job.text
        job_id = job.json()["id"]
        assert httpx.get(f"{outage_api.base_url}/readyz").json()["checks"]["postgresql"] == "ok"

        private_pg.stop()
        t0 = time.monotonic()
        for name, resp in _requests(client, job_id, scene_id).items():
            assert resp.status_code == 503, (name, resp.status_code, resp.text)
            assert resp.headers["Retry-After"] == RETRY_AFTER, name
            detail = assert_problem(resp, 503, "database-unavailable")["detail"]
            assert "records database (PostgreSQL) is unreachable" in detail and "\n" not in detail, detail
            assert "127.0.0.1" not in detail and str(private_pg.port) not in detail, detail  # no internals
        assert time.monotonic() - t0 < 30  # answered in seconds, not hung on TCP timeouts
        ready = httpx.get(f"{outage_api.base_url}/readyz")
        assert ready.status_code == 503 and ready.headers["Retry-After"] == RETRY_AFTER
        assert ready.json()["status"] == "degraded"
        checks = ready.json()["checks"]
        assert checks["postgresql"].startswith("error") and checks["redis"] == "ok" == checks["storage"]

        private_pg.start()
        deadline = time.monotonic() + 10
        while client.get(f"/v1/jobs/{job_id}").status_code != 200:
            assert time.monotonic() < deadline, "the API did not recover within 10 s of the restart"
            time.sleep(0.2)
        print(f"\nanswered again {time.monotonic() - deadline + 10:.1f} s after the restart")
        again = _requests(client, job_id, scene_id)
        assert again["GET job"].json()["id"] == job_id
        assert job_id in [j["id"] for j in again["GET jobs"].json()["items"]]
        assert again["GET usage"].status_code == 200 and again["GET scene"].status_code == 200
        assert again["POST job"].status_code == 202 and again["POST batch"].status_code == 202
        assert httpx.get(f"{outage_api.base_url}/readyz").status_code == 200
        # nothing a refused request sent was stored: the first job and the two sent after the restart
        assert len(client.get("/v1/jobs", params={"scene_id": scene_id}).json()["items"]) == 3
