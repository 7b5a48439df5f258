"""A job stored by an API that stopped before (or right after) enqueueing it runs, once.

Simulated on the real stack: the test stores the job exactly as the API's submission does
(quota slot, `JobStore.create`: an unsubmitted job row and its idempotency key) and then
"dies": no enqueue, or an enqueue without the confirmation. The workers' recovery scan (every
2 s, grace 3 s in these tests) must enqueue it; a duplicate message must not run any stage
twice (`stage_runs` stays 3, one per stage); a retry with the Idempotency-Key gets the job back.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import redis
from celery import Celery

from bayesian_fields_core.params import PipelineParams
from bayesian_fields_service.common.jobs import JobRecord, JobStore, new_id
from bayesian_fields_service.records.database import engine
from bayesian_fields_service.worker.dispatch import enqueue_stages
from tests.integration.fixtures.services import ApiServer

from .test_workers import PARAMS, TASKS, _upload, _wait, model_profile, worker_env, workers  # noqa: F401

pytestmark = [pytest.mark.integration, pytest.mark.slow]
TENANT = "tenant-a"


@pytest.fixture(scope="module")
def jobs(svc_env: dict[str, str], s3_server: Any) -> JobStore:
    redis_client = redis.Redis.from_url(svc_env["BFIELDS_REDIS_URL"])
    return JobStore(s3_server.store(), redis_client, engine(svc_env["BFIELDS_DATABASE_URL"]))


def _store_like_the_api(jobs: JobStore, scene_id: str, idem: str | None = None) -> JobRecord:
    params = PipelineParams.model_validate(PARAMS).model_dump(mode="json", exclude_unset=True)
    record = JobRecord(
        id=new_id("j_"),
        tenant=TENANT,
        scene_id=scene_id,
        tasks=TASKS,
        parameters=params,
        idempotency_key=idem,
    )
    ok, _ = jobs.quota.reserve(TENANT, [record.id], 100)
    assert ok
    jobs.create(record)
    return record


@pytest.mark.usefixtures("workers")
def test_a_job_never_enqueued_is_enqueued_by_recovery_and_runs_once(
    api: ApiServer, scene_dir: Path, jobs: JobStore
) -> None:
    scene_id = _upload(api, scene_dir)
    record = _store_like_the_api(jobs, scene_id, idem="unsubmitted-" + new_id("x"))
    with api.client(TENANT) as client:
        retry = client.post(
            "/v1/jobs",
            json={"scene_id": scene_id, "tasks": TASKS, "parameters": PARAMS},
            headers={"Idempotency-Key": record.idempotency_key or ""},
        )
        assert retry.status_code == 200 and retry.json() == {
            **retry.json(),
            "id": record.id,
            "created": False,
        }
        job = _wait(client, record.id, timeout_s=180)
    assert job["state"] == "succeeded", job
    assert job["stage_runs"] == 3 and job["attempts"] == 3, job
    assert (TENANT, record.id) not in jobs.pending_jobs()


@pytest.mark.usefixtures("workers")
def test_a_job_enqueued_but_not_confirmed_is_not_run_twice(
    api: ApiServer, scene_dir: Path, jobs: JobStore, svc_env: dict[str, str]
) -> None:
    """The API enqueued, then stopped before deleting the pending marker, so a second chain of
    messages may follow (recovery's, when the job still waits in the queue; sent here directly,
    since the workers pick the first up within the grace period): every stage still runs once."""
    scene_id = _upload(api, scene_dir)
    record = _store_like_the_api(jobs, scene_id)
    sender = Celery("bfields-test", broker=svc_env["BFIELDS_REDIS_URL"])
    for _ in range(2):
        enqueue_stages(sender, TENANT, record.id, record.remaining_stages(), gpu_queue="gpu", cpu_queue="cpu")
    with api.client(TENANT) as client:
        job = _wait(client, record.id, timeout_s=180)
    assert job["state"] == "succeeded", job
    assert job["stage_runs"] == 3, job
