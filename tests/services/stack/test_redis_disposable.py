"""Redis is disposable (issue 28, item 6), proven on the real stack: a fleet of 200 jobs with a batch
callback and usage accounting, two API processes (each with its control replica), real workers,
and Redis SIGKILLed mid-fleet and started again with no data at all.

Losing Redis loses the Celery messages, the live progress and the stage locks; the jobs, their
queue, the batch's counts, the callback outbox and the usage ledger are PostgreSQL's. So after
the loss: recovery sends the dispatched jobs again from their rows, the waiting ones were never
anywhere else, every job ends exactly once (none lost, none listed twice), the batch's callback
arrives once, and the usage ledger counts every end, the jobs cancelled while waiting included.
"""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import httpx
import pytest
import redis

from tests.integration.fixtures.s3_server import S3Server

from .fleet_stack import fleet_stack, submit_fleet
from .test_workers import _upload, _wait_for

# Longer than the default timeout (pyproject.toml): two fleet waits of up to 300 s each, after a stack start.
pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(900)]

FLEET = 200
TERMINAL = {"succeeded", "failed", "cancelled"}


def _states(client: httpx.Client, batch_id: str) -> dict[str, dict]:
    """Every job of the batch by id (paged through its listing)."""
    out: dict[str, dict] = {}
    cursor = None
    while True:
        page = client.get(
            f"/v1/batches/{batch_id}/jobs", params={"limit": 500, **({"cursor": cursor} if cursor else {})}
        )
        assert page.status_code == 200, page.text
        for job in page.json()["items"]:
            assert job["id"] not in out, f"{job['id']} listed twice"
            out[job["id"]] = job
        cursor = page.json()["next_cursor"]
        if not cursor:
            return out


def test_a_fleet_survives_losing_redis_with_callbacks_and_usage_exact(
    tmp_path: Path, s3_server: S3Server, test_api_keys: dict[str, str], worker_env: dict[str, str],
    scene_dir: Path,
) -> None:  # fmt: skip
    with fleet_stack(tmp_path, s3_server, test_api_keys, worker_env) as stack:
        redis_srv, apis, receiver = stack.redis, stack.apis, stack.receiver
        scene_id = _upload(apis[0], scene_dir)
        with apis[0].client("tenant-a") as a, apis[1].client("tenant-a") as b:
            batch_id = submit_fleet(a, scene_id, receiver, FLEET)

            def succeeded() -> int:
                return int(
                    b.get(f"/v1/batches/{batch_id}", params={"jobs": "false"})
                    .json()["counts"]
                    .get("succeeded", 0)
                )

            _wait_for(lambda: succeeded() >= 3 or None, 300, "3 jobs of the fleet")
            redis.Redis.from_url(redis_srv.url()).set("bf:test:before-the-loss", b"1")
            redis_srv.kill()  # SIGKILL, no persistence: queue messages, locks, live state gone
            redis_srv.start()
            # everything from before is gone (the workers and control process write again at once)
            assert redis.Redis.from_url(redis_srv.url()).get("bf:test:before-the-loss") is None
            lost_at = succeeded()
            _wait_for(lambda: succeeded() >= lost_at + 5 or None, 300, "5 more jobs after the loss")
            cancel = b.post(f"/v1/batches/{batch_id}/cancel")  # the rest: most of them still waiting
            assert cancel.status_code == 202, cancel.text
            _wait_for(lambda: b.get(f"/v1/batches/{batch_id}", params={"jobs": "false"}).json()["finished"] or None,
                      300, "every job of the fleet to end")  # fmt: skip
            jobs = _states(a, batch_id)
            usage = a.get("/v1/usage").json()["total"]
        states = Counter(j["state"] for j in jobs.values())
        print(f"\nfleet of {FLEET} after losing Redis: {dict(states)}; usage {usage['jobs_by_state']}")
        assert len(jobs) == FLEET and set(states) <= TERMINAL, states
        assert states["succeeded"] >= lost_at + 5 and states["cancelled"] >= FLEET // 2, states
        for job in jobs.values():
            if job["state"] == "failed":  # a stage cut off by the loss: failed with its reason
                assert job["error"], job
        # every end counted once, the jobs cancelled while waiting included
        assert usage["jobs"] == FLEET and usage["jobs_by_state"] == dict(states), usage
        _wait_for(lambda: len(receiver.snapshot()) >= 1 or None, 60, "the batch callback")
        time.sleep(2.0)  # and no second one
        hits = receiver.snapshot()
        assert len(hits) == 1 and hits[0].event_id.startswith(f"batch:{batch_id}:finished:"), hits
