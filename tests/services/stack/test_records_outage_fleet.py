"""The records database is a fault the service survives (issue 41, item 8), proven on the real
stack: a fleet of 200 jobs with a batch callback plus 10 single jobs with their own callbacks,
two API processes (each with its control replica), real workers, and the stack's own PostgreSQL
server stopped for 20 s mid-fleet (never the shared one).

During the outage clients see only answers they can act on (503 with Retry-After, never a 500);
workers wait for their writes to land; the control replicas lose and retake the lease. After it:
every job ends exactly once (none lost, none listed twice), no finished job ran a stage twice,
each callback arrives once, and the usage ledger counts every end once.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from pathlib import Path

import httpx
import pytest

from tests.integration.fixtures.private_postgres import PrivatePostgres, postgres_bin
from tests.integration.fixtures.s3_server import S3Server
from tests.integration.fixtures.services import ApiServer

from .fleet_stack import fleet_stack, submit_fleet
from .test_redis_disposable import TERMINAL, _states
from .test_workers import PARAMS, TASKS, _upload, _wait_for

pytestmark = [
    pytest.mark.integration,
    pytest.mark.slow,
    pytest.mark.timeout(900),
    pytest.mark.skipif(postgres_bin() is None, reason="no PostgreSQL binaries to start a private server"),
]

FLEET = 200
SINGLES = 10
OUTAGE_S = 20


def _json(client: httpx.Client, path: str) -> dict:
    """GET `path`, waiting out the 503s of a database that is coming back."""
    deadline = time.monotonic() + 60
    while True:
        resp = client.get(path)
        if resp.status_code != 503 or time.monotonic() > deadline:
            assert resp.status_code == 200, resp.text
            return dict(resp.json())
        time.sleep(0.5)


class Watcher:
    """A client polling the API through the outage from its own thread, recording every answer."""

    def __init__(self, api: ApiServer, paths: list[str]) -> None:
        self.api, self.paths = api, paths
        self.codes: Counter[int] = Counter()
        self.bad: list[str] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        with self.api.client("tenant-a") as client:
            while not self.stop.is_set():
                for path in self.paths:
                    try:
                        resp = client.get(path, timeout=10)
                    except httpx.HTTPError as exc:
                        self.bad.append(f"{path}: {type(exc).__name__}")
                        continue
                    self.codes[resp.status_code] += 1
                    if resp.status_code == 503 and "retry-after" not in resp.headers:
                        self.bad.append(f"{path}: 503 without Retry-After")
                    elif resp.status_code not in (200, 503):
                        self.bad.append(f"{path}: {resp.status_code} {resp.text[:200]}")
                time.sleep(0.2)


def test_a_fleet_survives_a_records_database_outage_with_callbacks_and_usage_exact(
    tmp_path: Path, s3_server: S3Server, test_api_keys: dict[str, str], worker_env: dict[str, str],
    scene_dir: Path, private_pg: PrivatePostgres,
) -> None:  # fmt: skip
    watcher: Watcher | None = None
    with fleet_stack(tmp_path, s3_server, test_api_keys, worker_env,
                     {"BFIELDS_DATABASE_URL": private_pg.url()}) as stack:  # fmt: skip
        try:
            apis, receiver = stack.apis, stack.receiver
            scene_id = _upload(apis[0], scene_dir)
            with apis[0].client("tenant-a") as a, apis[1].client("tenant-a") as b:
                batch_id = submit_fleet(a, scene_id, receiver, FLEET)
                singles = []
                for i in range(SINGLES):
                    resp = b.post("/v1/jobs", json={"scene_id": scene_id, "tasks": [f"{TASKS[1]} {i}"],
                                                    "parameters": PARAMS, "callback_url": receiver.url(f"/job/{i}")})  # fmt: skip
                    assert resp.status_code == 202, resp.text
                    singles.append(resp.json()["id"])

                def succeeded() -> int:
                    return int(_json(b, f"/v1/batches/{batch_id}")["counts"].get("succeeded", 0))

                _wait_for(lambda: succeeded() >= 3 or None, 300, "3 jobs of the fleet")
                watcher = Watcher(
                    apis[1], [f"/v1/batches/{batch_id}", f"/v1/jobs/{singles[-1]}", "/v1/jobs?limit=5"]
                )
                watcher.thread.start()
                private_pg.stop()  # every process loses the records at once
                time.sleep(OUTAGE_S)
                private_pg.start()
                _wait_for(lambda: all(_json(b, f"/v1/jobs/{j}")["state"] in TERMINAL for j in singles) or None,
                      300, "every single job to end")  # fmt: skip
                lost_at = succeeded()
                _wait_for(lambda: succeeded() >= lost_at + 5 or None, 300, "5 more jobs after the outage")
                watcher.stop.set()
                watcher.thread.join(15)
                cancel = b.post(f"/v1/batches/{batch_id}/cancel")  # the rest: most of them still waiting
                assert cancel.status_code == 202, cancel.text
                _wait_for(lambda: _json(b, f"/v1/batches/{batch_id}")["finished"] or None, 300,
                      "every job of the fleet to end")  # fmt: skip
                jobs = _states(a, batch_id)
                single_jobs = [a.get(f"/v1/jobs/{j}").json() for j in singles]
                usage = a.get("/v1/usage").json()["total"]
            states = Counter(j["state"] for j in jobs.values())
            print(f"\nfleet of {FLEET} + {SINGLES} through a {OUTAGE_S} s records outage: {dict(states)}; "
              f"clients saw {dict(watcher.codes)}; usage {usage['jobs_by_state']}")  # fmt: skip
            assert watcher.bad == [], watcher.bad[:10]
            assert watcher.codes[503] > 0, "the outage was never seen by a client"
            assert len(jobs) == FLEET and set(states) <= TERMINAL, states
            assert [j["state"] for j in single_jobs] == ["succeeded"] * SINGLES, single_jobs
            ran = [j for j in [*jobs.values(), *single_jobs] if j["state"] == "succeeded"]
            assert all(j["stage_runs"] == 3 for j in ran), [
                (j["id"], j["stage_runs"]) for j in ran if j["stage_runs"] != 3
            ]
            ends = Counter(j["state"] for j in [*jobs.values(), *single_jobs])
            assert usage["jobs"] == FLEET + SINGLES and usage["jobs_by_state"] == dict(ends), usage
            _wait_for(lambda: len(receiver.snapshot()) >= SINGLES + 1 or None, 60, "every callback")
            time.sleep(2.0)  # and no second one
            hits = Counter(hit.event_id for hit in receiver.snapshot())
            assert len(hits) == SINGLES + 1 and set(hits.values()) == {1}, hits
        finally:
            if watcher is not None:
                watcher.stop.set()
