"""A job's claim on its row against crashes, with real prefork workers on a private Redis and
recovery scans switched off (so only the stage task's own retry logic can finish a job):
- a pool child SIGKILLed mid-stage: Celery requeues the message at once; the new child sees that
  the claim's owner process is dead and takes the claim over, and the job completes;
- a claim held by a process on another host (which cannot be checked): the delivery waits with
  countdowns of the claim's remaining lease, however many that takes, and runs once it lapsed.
Before, both waited at most 3 retries of a quarter TTL each, far less than the TTL, and then gave
up with the job left 'running'."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import pytest
from sqlalchemy import Engine, func, select, update

from bayesian_fields_service.records.database import engine
from bayesian_fields_service.records.tables import jobs
from tests.services.conftest import SERVICE_ENV
from tests.services.support.private_stack import PrivateStack, pool_children, upload, wait_job
from tests.services.support.scene_factory import make_scene

# Longer than the default timeout (pyproject.toml): a job waits out a 20 s foreign lock (its own deadline 260 s) on a 16-frame scene.
pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(600)]

TASKS = ["red blob", "green blob"]
FOREIGN_LOCK_S = 20
LEASE_S = 60


def _database(stack: PrivateStack) -> Engine:
    return engine(stack.env["BFIELDS_DATABASE_URL"])


def _claim_for(stack: PrivateStack, job_id: str, worker: str, *, beaten_s_ago: float) -> None:
    """Write a claim on the job's row as a worker elsewhere would have (`records.job_heartbeats`)."""
    beaten = func.now() - func.make_interval(0, 0, 0, 0, 0, 0, beaten_s_ago)
    with _database(stack).begin() as conn:
        conn.execute(update(jobs).where(jobs.c.id == job_id).values(worker=worker, heartbeat_at=beaten))


def _holder(stack: PrivateStack, job_id: str) -> str | None:
    with _database(stack).connect() as conn:
        return conn.execute(select(jobs.c.worker).where(jobs.c.id == job_id)).scalar()


@pytest.fixture(scope="module")
def big_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """More and larger frames than the other tests': perceive lasts long enough to be hit."""
    return make_scene(tmp_path_factory.mktemp("crash-scene") / "s", frames=16, width=128, height=96)


@pytest.fixture(scope="module")
def stack(private_stacks: Callable[[str, Mapping[str, str]], PrivateStack]) -> PrivateStack:
    extra = {
        **SERVICE_ENV,
        "BFIELDS_RECOVERY_GRACE_S": "36000",  # no rescue by recovery scans
        # the production TTL: a requeued delivery could not just outwait a short one by accident
        "BFIELDS_STAGE_LOCK_TTL_S": str(LEASE_S),
    }
    stack = private_stacks("crash-stack", extra).start()
    assert stack.pool is not None
    stack.pool.start("cpu")
    return stack


def test_lock_of_another_host_is_waited_out(stack: PrivateStack, big_scene: Path) -> None:
    assert stack.api is not None and stack.pool is not None
    with stack.api.client("tenant-a") as client:
        scene_id = upload(client, big_scene)
        job_id = client.post(
            "/v1/jobs", json={"scene_id": scene_id, "tasks": TASKS, "parameters": {"max_frames": 4}}
        ).json()["id"]
        # a holder on another machine (its liveness cannot be checked from here), whose claim on
        # the job's row lapses FOREIGN_LOCK_S from now (its last beat LEASE_S - FOREIGN_LOCK_S ago)
        _claim_for(stack, job_id, f"another-host:4242:1:{'0' * 16}", beaten_s_ago=LEASE_S - FOREIGN_LOCK_S)
        t0 = time.monotonic()
        gpu = stack.pool.start("gpu", pool="prefork")
        job = wait_job(client, job_id, timeout_s=FOREIGN_LOCK_S + 240)
    assert job["state"] == "succeeded", job
    assert time.monotonic() - t0 >= FOREIGN_LOCK_S - 2  # it did wait for the lock
    assert "is locked; retry in" in gpu.log_text()
    gpu.stop()


def test_pool_child_killed_mid_stage_job_completes(stack: PrivateStack, big_scene: Path) -> None:
    assert stack.api is not None and stack.pool is not None
    gpu = stack.pool.start("gpu", pool="prefork")
    with stack.api.client("tenant-a") as client:
        scene_id = upload(client, big_scene)
        job_id = client.post(
            "/v1/jobs", json={"scene_id": scene_id, "tasks": TASKS, "parameters": {"max_frames": 16}}
        ).json()["id"]
        deadline = time.monotonic() + 120
        while _holder(stack, job_id) is None:  # the child claimed the job: it is mid-stage
            assert time.monotonic() < deadline, "perceive never started"
            time.sleep(0.05)
        assert gpu.process.pid is not None
        (child,) = pool_children(gpu.process.pid)  # concurrency 1: the child running the stage
        os.kill(child, signal.SIGKILL)
        job = wait_job(client, job_id, timeout_s=300)
    assert job["state"] == "succeeded", job
    assert job["attempts"] >= 2  # the killed execution and the one that took the lock over
    log = gpu.log_text()
    assert "signal 9" in log or "WorkerLostError" in log, log[-3000:]
    assert "is dead; taken over" in log
    gpu.stop()
