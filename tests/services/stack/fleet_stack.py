"""The stack of the fleet fault tests (Redis lost, the records database stopped): a Redis of the
test's own without persistence (so a kill loses everything), two API processes with the control
process, a GPU-queue and a CPU-queue Celery worker, callbacks on to a receiver in the test, and the
fleet they submit. One place, so both faults are tried on the very same stack."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import httpx

from tests.integration.fixtures.redis_server import RedisServer
from tests.integration.fixtures.s3_server import S3Server
from tests.integration.fixtures.services import ApiServer, WorkerPool, build_service_env
from tests.services.conftest import SERVICE_ENV
from tests.services.support.callback_receivers import Receiver

from .test_workers import PARAMS, TASKS

CALLBACKS_ON = {"BFIELDS_CALLBACK_SECRET": "test-secret", "BFIELDS_CALLBACK_ALLOW_PRIVATE": "true",
                "BFIELDS_CALLBACK_POLL_S": "0.2", "BFIELDS_DISPATCH_INTERVAL_S": "0.2"}  # fmt: skip


@dataclass
class FleetStack:
    redis: RedisServer
    apis: list[ApiServer]
    pool: WorkerPool
    receiver: Receiver


@contextmanager
def fleet_stack(
    tmp_path: Path, s3_server: S3Server, keys: Mapping[str, str], worker_env: Mapping[str, str],
    settings: Mapping[str, str] | None = None,
) -> Iterator[FleetStack]:  # fmt: skip
    """The stack started (`settings` on top of the tests' service settings and callbacks on), and
    stopped whatever the test did."""
    receiver = Receiver("ok")
    redis_srv = RedisServer(tmp_path / "redis", appendonly=False).start()
    env = build_service_env(
        tmp_path / "env", redis_srv.url(), s3_server.env(), keys,
        {**SERVICE_ENV, **worker_env, **CALLBACKS_ON, **(settings or {})},
    )  # fmt: skip
    apis: list[ApiServer] = []
    pool = WorkerPool(broker_url=redis_srv.url(), env=env, log_dir=tmp_path / "workers")
    try:
        apis += [ApiServer(env=env, log_dir=tmp_path / f"api{i}", keys=dict(keys)).start() for i in range(2)]
        pool.start("gpu")
        pool.start("cpu")
        yield FleetStack(redis_srv, apis, pool, receiver)
    finally:
        pool.stop_all()
        for api in apis:
            api.stop()
        redis_srv.stop()
        receiver.close()


def submit_fleet(client: httpx.Client, scene_id: str, receiver: Receiver, size: int) -> str:
    """A batch of `size` jobs on one scene, with its batch callback; its id."""
    batch = client.post("/v1/batches", json={
        "scene_ids": [scene_id], "task_lists": [[f"{TASKS[0]} {i}"] for i in range(size)],
        "parameters": PARAMS, "callback_url": receiver.url("/batch"),
    })  # fmt: skip
    assert batch.status_code == 202 and batch.json()["created"] == size, batch.text
    return str(batch.json()["id"])
