"""The stuck job of issue 41, made deterministic: the records database stops at the moment a job's
last write is due, and the job still ends succeeded, its callback sent once, its usage counted once.

The worker holds the job at the cluster stage's 1.0 progress point (the result written, the stage's
end and the job's end not yet), the test stops the stack's own PostgreSQL server (never the shared
one), lets the worker go on into the outage for 20 s, and starts the server again. Before, the
worker's write failed once and the row stayed unfinished for good (recovery requeued it again and
again with no stage left to send); now the worker retries its writes until they land
(`jobs.durable_writes`), and recovery would finish such a job from its row if they never did.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from sqlalchemy import create_engine, select

from bayesian_fields_service.records.tables import callback_outbox, usage_ledger
from tests.integration.fixtures.private_postgres import PrivatePostgres, postgres_bin
from tests.services.stack.test_fleet_notify import FLEET_ENV, Receiver
from tests.services.stack.test_workers import PARAMS, TASKS
from tests.services.support.private_stack import PrivateStack, upload
from tests.services.support.service_hooks import PLUGIN_ENV, arm, resume, wait_reached

pytestmark = [
    pytest.mark.integration,
    pytest.mark.slow,
    pytest.mark.timeout(600),
    pytest.mark.skipif(postgres_bin() is None, reason="no PostgreSQL binaries to start a private server"),
]

#: How long the database stays away once the worker is past its pause point (the measured outage).
OUTAGE_S = 20


@pytest.fixture
def receiver() -> Iterator[Receiver]:
    r = Receiver()
    yield r
    r.close()


def _wait_final(client: httpx.Client, job_id: str, timeout_s: float) -> dict[str, Any]:
    """The job once terminal, asking through 503s (the API answers those while the database is away)."""
    deadline = time.monotonic() + timeout_s
    last: Any = None
    while time.monotonic() < deadline:
        try:
            resp = client.get(f"/v1/jobs/{job_id}")
        except httpx.HTTPError as exc:
            last = exc
        else:
            last = resp.status_code
            if resp.status_code == 200 and resp.json()["state"] in ("succeeded", "failed", "cancelled"):
                return dict(resp.json())
            assert resp.status_code in (200, 503), resp.text  # never a 500
        time.sleep(0.5)
    raise AssertionError(f"job {job_id} did not end in {timeout_s} s (last answer {last})")


def test_a_final_write_racing_a_database_outage_ends_succeeded_once(
    private_stacks: Any, private_pg: PrivatePostgres, receiver: Receiver, scene_dir: Path
) -> None:
    stack: PrivateStack = private_stacks(
        "final-write",
        {**FLEET_ENV, "BFIELDS_DATABASE_URL": private_pg.url(), **PLUGIN_ENV},
    )
    stack.start()
    assert stack.pool is not None and stack.api is not None
    stack.pool.start("gpu")
    stack.pool.start("cpu")
    with stack.api.client("tenant-a") as client:
        scene_id = upload(client, scene_dir)
        resp = client.post("/v1/jobs", json={"scene_id": scene_id, "tasks": TASKS, "parameters": PARAMS,
                                             "callback_url": receiver.url("/job")})  # fmt: skip
        assert resp.status_code == 202, resp.text
        job_id = resp.json()["id"]
        arm(stack.redis, "progress:cluster:1", job_id)
        wait_reached(stack.redis, "progress:cluster:1", job_id, timeout_s=240)
        private_pg.stop()  # the moment of the final write
        resume(stack.redis, "progress:cluster:1", job_id)
        time.sleep(OUTAGE_S)
        private_pg.start()
        job = _wait_final(client, job_id, 180)
    assert job["state"] == "succeeded", job
    # the worker's write met the outage and was tried again until it landed
    logs = "".join(p.read_text(errors="replace") for p in (stack.tmp / "workers").rglob("*.log"))
    assert "the records database is unreachable" in logs and job_id in logs
    assert job["stage_runs"] == 3, job  # no stage ran again
    # This receiver answers 500 to an event's first attempt: delivered means exactly two hits of one event.
    deadline = time.monotonic() + 60
    while len(receiver.hits("/job")) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(3)  # a duplicate would come within the sender's poll interval
    bodies = [json.loads(hit["body"]) for hit in receiver.hits("/job")]
    assert len(bodies) == 2 and {b["event_id"] for b in bodies} == {bodies[0]["event_id"]}, bodies
    assert bodies[0]["state"] == "succeeded" and bodies[0]["job_id"] == job_id
    database = create_engine(private_pg.url())
    try:
        with database.connect() as conn:
            ledger = conn.execute(
                select(usage_ledger.c.kind, usage_ledger.c.stage).where(usage_ledger.c.job_id == job_id)
            ).all()
            events = conn.execute(
                select(callback_outbox.c.event_id).where(callback_outbox.c.url == receiver.url("/job"))
            ).all()
    finally:
        database.dispose()
    assert sorted((k, s or "") for k, s in ledger) == [
        ("end", ""), ("stage", "cluster"), ("stage", "fuse"), ("stage", "perceive")
    ]  # fmt: skip
    assert len(events) == 1
