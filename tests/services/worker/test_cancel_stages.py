"""A cancel accepted while the cluster stage runs stops the job: cancelled, no result, slot freed.

Real workers; the worker holds the job at a progress pause point (`tests/services/support/service_hooks.py`):
cluster at 0.8 (objects found, result not yet written) and at 1.0 (result written, job not yet
marked succeeded), the two places where a cancel used to be ignored.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest
import redis

from bayesian_fields_service.jobs.queue import JobQueue
from bayesian_fields_service.records.database import engine
from tests.integration.fixtures.services import ApiServer
from tests.services.stack.test_workers import PARAMS, TASKS, _upload
from tests.services.support.private_stack import wait_job
from tests.services.support.service_hooks import arm, resume, wait_reached

# Longer than the default timeout (pyproject.toml): its own waits: 240 s for the pause point, then 120 s for the job.
pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(600)]


@pytest.fixture(scope="module")
def rdb(svc_env: dict[str, str]) -> redis.Redis:
    return redis.Redis.from_url(svc_env["BFIELDS_REDIS_URL"])


@pytest.mark.usefixtures("workers")
@pytest.mark.parametrize("point", ["progress:cluster:0.8", "progress:cluster:1"])
def test_a_cancel_accepted_in_the_cluster_stage_is_honoured(
    point: str, api: ApiServer, scene_dir: Path, rdb: redis.Redis, s3_server: Any
) -> None:
    scene_id = _upload(api, scene_dir)
    with api.client("tenant-a") as client:
        resp = client.post("/v1/jobs", json={"scene_id": scene_id, "tasks": TASKS, "parameters": PARAMS})
        assert resp.status_code == 202, resp.text
        job_id = resp.json()["id"]
        arm(rdb, point, job_id)
        wait_reached(rdb, point, job_id, timeout_s=240)
        accepted = client.delete(f"/v1/jobs/{job_id}")
        assert accepted.status_code == 202 and accepted.json()["cancel_requested"] is True, accepted.text
        resume(rdb, point, job_id)
        job = wait_job(client, job_id, timeout_s=120)
        assert job["state"] == "cancelled", job
        assert client.get(f"/v1/jobs/{job_id}/result").status_code == 409
    bucket = s3_server.store()
    prefix = f"tenants/tenant-a/jobs/{job_id}/"
    assert bucket.list(prefix + "result/") == []
    assert not bucket.exists(prefix + "stages/cluster.json")
    deadline = time.monotonic() + 10
    while bucket.exists(f"active/tenant-a/{job_id}") and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not bucket.exists(f"active/tenant-a/{job_id}"), "the job's slot marker was not freed"
    active = JobQueue(engine(api.env["BFIELDS_DATABASE_URL"])).dispatched_ids("tenant-a")
    assert job_id not in active, "the job still counts against its tenant's dispatch bound"


@pytest.mark.usefixtures("workers")
def test_a_cancel_after_success_is_not_accepted(api: ApiServer, scene_dir: Path) -> None:
    """The other order: the job succeeded first; the cancel leaves it succeeded and says so."""
    scene_id = _upload(api, scene_dir)
    with api.client("tenant-a") as client:
        job_id = client.post(
            "/v1/jobs", json={"scene_id": scene_id, "tasks": TASKS, "parameters": PARAMS}
        ).json()["id"]
        assert wait_job(client, job_id)["state"] == "succeeded"
        late = client.delete(f"/v1/jobs/{job_id}")
        assert late.json()["state"] == "succeeded" and late.json()["cancel_requested"] is False
        assert client.get(f"/v1/jobs/{job_id}/result").status_code == 200
