"""Fleets on the real stack (Redis, rclone S3, uvicorn, Celery workers with a prefork pool of 3 so
jobs really race): 20 jobs started together on one scene compute perception once (counted by the
encoder itself, across processes), a batch's event stream, signed callbacks received by a real
HTTP server (retried after a failure), and the per-job / per-tenant usage."""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import secrets
import threading
import time
from collections.abc import Iterator
from datetime import UTC, datetime
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import httpx
import pytest
from standardwebhooks import Webhook

from tests.integration.fixtures.postgres import create_database, drop_database
from tests.integration.fixtures.services import ApiServer, WorkerPool
from tests.services.conftest import SERVICE_ENV, scene_form
from tests.services.support.scene_factory import make_scene
from tests.services.support.service_hooks import ENCODER_CALL_LOG_ENV

# Longer than the default timeout (pyproject.toml): a fleet on prefork workers; its callback wait alone may take 240 s.
pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(600)]

SECRET = "test-callback-secret"
IDLE_TENANT = "tenant-idle"
FRAMES = 8
JOBS = 20
PARAMS = {"max_frames": FRAMES}


class Receiver:
    """A real HTTP server taking callbacks; answers 500 to the first attempt of every event."""

    def __init__(self) -> None:
        self.received: list[dict] = []
        self.lock = threading.Lock()
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802
                body = self.rfile.read(int(self.headers["Content-Length"]))
                hit = {"body": body, "headers": dict(self.headers), "path": self.path}
                with outer.lock:
                    first = not any(r["headers"].get("webhook-id") == hit["headers"].get("webhook-id")
                                    for r in outer.received)  # fmt: skip
                    outer.received.append(hit)
                self.send_response(500 if first else 204)
                self.end_headers()

            def log_message(self, *args: object) -> None:
                return

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def url(self, path: str) -> str:
        return f"http://127.0.0.1:{self.server.server_address[1]}{path}"

    def hits(self, path: str) -> list[dict]:
        with self.lock:
            return [r for r in self.received if r["path"] == path]

    def close(self) -> None:
        self.server.shutdown()


FLEET_ENV = {
    "BFIELDS_CALLBACK_SECRET": SECRET,
    "BFIELDS_CALLBACK_ALLOW_PRIVATE": "true",  # the receiver is on 127.0.0.1
    "BFIELDS_CALLBACK_BACKOFF_S": "0.5",
    "BFIELDS_CALLBACK_POLL_S": "0.2",
    "BFIELDS_EVENTS_POLL_S": "0.3",
    "BFIELDS_FLIGHT_LOCK_TTL_S": "6",
    "BFIELDS_FLIGHT_POLL_S": "0.1",
}


@pytest.fixture(scope="module")
def encoder_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("encoder") / "calls.log"


@pytest.fixture(scope="module")
def fleet_database() -> Iterator[str]:
    """A records database of this module's own: its control process (with the callback settings
    above) leads there, instead of standing by behind the session's, which sends no callbacks."""
    url = create_database()
    yield url
    drop_database(url)


@pytest.fixture(scope="module")
def fleet_api(
    tmp_path_factory: pytest.TempPathFactory, service_env: dict[str, str], test_api_keys: dict[str, str],
    fleet_database: str,
) -> Iterator[ApiServer]:  # fmt: skip
    # tenant-idle runs nothing anywhere in the session: its usage must read 0 whatever ran before
    keys = {**test_api_keys, IDLE_TENANT: "key-idle-" + secrets.token_urlsafe(16)}
    env = {**service_env, **SERVICE_ENV, **FLEET_ENV, "BFIELDS_DATABASE_URL": fleet_database,
           "BFIELDS_API_KEYS": json.dumps({key: tenant for tenant, key in keys.items()})}  # fmt: skip
    server = ApiServer(
        env=env,
        log_dir=tmp_path_factory.mktemp("fleet-api"),
        keys=keys,
    ).start()
    yield server
    server.stop()


@pytest.fixture(scope="module")
def fleet_workers(
    celery_workers: WorkerPool,
    worker_env: dict[str, str],
    encoder_log: Path,
    fleet_database: str,
) -> Iterator[WorkerPool]:
    env = {**SERVICE_ENV, **FLEET_ENV, **worker_env, ENCODER_CALL_LOG_ENV: str(encoder_log),
           "BFIELDS_DATABASE_URL": fleet_database}  # fmt: skip
    started = [
        celery_workers.start("gpu", pool="prefork", concurrency=3, extra_env=env),
        celery_workers.start("cpu", pool="prefork", concurrency=2, extra_env=env),
    ]
    yield celery_workers
    for worker in started:
        if worker.alive:
            worker.stop()


@pytest.fixture(scope="module")
def receiver() -> Iterator[Receiver]:
    r = Receiver()
    yield r
    r.close()


def _events(api: ApiServer, batch_id: str, out: list[tuple[str, dict]], timeout_s: float) -> None:
    """Read the batch's SSE stream until `end` (the test thread's own HTTP client)."""
    with (
        httpx.Client(base_url=api.base_url, headers=api.headers("tenant-a"), timeout=timeout_s) as client,
        client.stream("GET", f"/v1/batches/{batch_id}/events") as resp,
    ):
        assert resp.status_code == 200 and resp.headers["content-type"].startswith("text/event-stream")
        name = None
        for line in resp.iter_lines():
            if line.startswith("event: "):
                name = line[7:]
            elif line.startswith("data: ") and name:
                out.append((name, json.loads(line[6:])))
                if name == "end":
                    return


@pytest.fixture(scope="module")
def fleet(
    fleet_api: ApiServer,
    fleet_workers: WorkerPool,
    receiver: Receiver,
    tmp_path_factory: pytest.TempPathFactory,
) -> dict:
    """One scene, then a batch of 20 jobs on it (distinct task lists) submitted in one request,
    with the event stream read while they run; returns what the tests check."""
    scene_dir = make_scene(tmp_path_factory.mktemp("fleet-scene") / "s", frames=FRAMES)
    with fleet_api.client("tenant-a") as client:
        resp = client.post("/v1/scenes", files=scene_form(scene_dir), data={"name": "fleet"})
        assert resp.status_code == 201, resp.text
        scene_id = resp.json()["id"]
        tasks = [[f"blob number {n}", "red blob"] for n in range(JOBS)]
        started = time.monotonic()
        resp = client.post("/v1/batches", json={
            "scene_ids": [scene_id], "task_lists": tasks, "parameters": PARAMS,
            "callback_url": receiver.url("/batch"),
        })  # fmt: skip
        assert resp.status_code == 202, resp.text
        batch = resp.json()
        events: list[tuple[str, dict]] = []
        reader = threading.Thread(target=_events, args=(fleet_api, batch["id"], events, 600), daemon=True)
        reader.start()
        reader.join(600)
        assert not reader.is_alive(), "the event stream did not end"
        seconds = time.monotonic() - started
        jobs = [client.get(f"/v1/jobs/{j['id']}").json() for j in batch["jobs"]]
    return {"batch": batch, "jobs": jobs, "events": events, "seconds": seconds, "scene_id": scene_id}


def test_twenty_jobs_on_one_scene_perceive_once(fleet: dict, encoder_log: Path) -> None:
    jobs = fleet["jobs"]
    assert [j["state"] for j in jobs] == ["succeeded"] * JOBS, [j.get("error") for j in jobs]
    computed = [j["stage_reports"]["perceive"]["frames_computed"] for j in jobs]
    rendered = [j["stage_reports"]["fuse"]["frames_rendered"] for j in jobs]
    calls = encoder_log.read_text().splitlines()
    print(f"\n{JOBS} jobs x {FRAMES} frames in {fleet['seconds']:.1f} s: encoder image batches {len(calls)}, "
          f"frames segmented {sum(computed)}, frames rendered for visibility {sum(rendered)}")  # fmt: skip
    assert sum(computed) == FRAMES and computed.count(FRAMES) == 1  # one job computed, 19 reused it
    assert sum(rendered) == FRAMES and rendered.count(FRAMES) == 1
    # the encoder itself counted its calls in every worker process: one perception's worth
    one_run = next(j for j in jobs if j["stage_reports"]["perceive"]["frames_computed"])
    assert len(calls) == one_run["stage_reports"]["perceive"]["encoder_calls"] > 0


def test_batch_event_stream(fleet: dict) -> None:
    events = fleet["events"]
    names = [n for n, _ in events]
    assert names[-1] == "end" and names.count("end") == 1
    first_round = [d for n, d in events[:JOBS] if n == "job"]
    assert len(first_round) == JOBS  # a full picture first
    final = [d for n, d in events if n == "counts"][-1]
    assert final == {"counts": {"succeeded": JOBS}, "total": JOBS, "progress": 100.0, "finished": True}
    per_job: dict[str, list[str]] = {}
    for n, d in events:
        if n == "job":
            per_job.setdefault(d["id"], []).append(d["state"])
    assert set(per_job) == {j["id"] for j in fleet["jobs"]}
    assert all(states[-1] == "succeeded" for states in per_job.values())
    assert any("running" in states for states in per_job.values())  # seen while it ran


def _check_signature(hit: dict) -> dict:
    """The callback verifies with the Standard Webhooks library (given the `whsec_` form of the raw
    secret, as `bfields-service callback-secret` prints it) and by the deprecated header."""
    event = Webhook("whsec_" + base64.b64encode(SECRET.encode()).decode()).verify(hit["body"], hit["headers"])
    ts, sig = hit["headers"]["X-BFields-Timestamp"], hit["headers"]["X-BFields-Signature"]
    expected = (
        "sha256=" + hmac.new(SECRET.encode(), ts.encode() + b"." + hit["body"], hashlib.sha256).hexdigest()
    )
    assert hmac.compare_digest(sig, expected)
    assert abs(time.time() - int(ts)) < 120
    assert event == json.loads(hit["body"])
    return dict(event)


def _wait_hits(receiver: Receiver, path: str, n: int, timeout_s: float = 60) -> list[dict]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        hits = receiver.hits(path)
        if len(hits) >= n:
            return hits
        time.sleep(0.2)
    raise AssertionError(f"{path}: {len(receiver.hits(path))} callbacks, wanted {n}")


def test_batch_callback_is_signed_and_retried(fleet: dict, receiver: Receiver) -> None:
    hits = _wait_hits(receiver, "/batch", 2)  # the first attempt got a 500: sent again
    time.sleep(1.0)
    hits = receiver.hits("/batch")
    assert len(hits) == 2  # delivered (204) once after the failure; no more
    bodies = [_check_signature(h) for h in hits]
    assert bodies[0] == bodies[1]  # the same event, the same idempotency key
    assert bodies[0]["type"] == "batch.finished" and bodies[0]["batch_id"] == fleet["batch"]["id"]
    assert bodies[0]["counts"] == {"succeeded": JOBS} and bodies[0]["jobs"] == JOBS
    assert hits[0]["headers"]["X-BFields-Event-Id"] == bodies[0]["event_id"]
    assert hits[0]["headers"]["webhook-id"] == hits[1]["headers"]["webhook-id"]  # one id, both attempts
    # the batch's jobs send none of their own
    assert receiver.hits("/job") == []


def test_job_callback_and_url_rules(fleet: dict, fleet_api: ApiServer, receiver: Receiver) -> None:
    with fleet_api.client("tenant-a") as client:
        for bad in ("ftp://127.0.0.1/x", "http://user:pw@127.0.0.1/x", "file:///etc/passwd"):
            resp = client.post(
                "/v1/jobs", json={"scene_id": fleet["scene_id"], "tasks": ["a"], "callback_url": bad}
            )
            assert resp.status_code == 422 and "callback_url" in resp.text, resp.text
        resp = client.post("/v1/jobs", json={
            "scene_id": fleet["scene_id"], "tasks": ["green blob"], "parameters": PARAMS,
            "callback_url": receiver.url("/job"),
        })  # fmt: skip
        assert resp.status_code == 202, resp.text
        job_id = resp.json()["id"]
    hits = _wait_hits(receiver, "/job", 2, timeout_s=240)
    body = _check_signature(hits[-1])
    assert body["type"] == "job.finished" and body["job_id"] == job_id and body["state"] == "succeeded"
    assert body["event_id"] == _check_signature(hits[0])["event_id"]
    assert hits[0]["headers"]["webhook-id"] == hits[-1]["headers"]["webhook-id"]


def test_usage_per_job_and_per_tenant(fleet: dict, fleet_api: ApiServer) -> None:
    jobs = fleet["jobs"]
    for job in jobs:
        usage = job["usage"]
        assert set(usage["cpu_seconds"]) == {"perceive", "fuse", "cluster"}
        assert usage["gpu_seconds"] == {"perceive": 0.0, "fuse": 0.0, "cluster": 0.0}  # CPU workers
        assert usage["bytes_stored"] > 0 and usage["cpu_seconds_total"] > 0
    computing = next(j for j in jobs if j["stage_reports"]["perceive"]["frames_computed"])
    reusing = [j["usage"]["cpu_seconds"]["perceive"] for j in jobs if j is not computing]
    assert computing["usage"]["cpu_seconds"]["perceive"] > max(reusing)  # reuse costs less
    today = datetime.now(UTC).date().isoformat()
    with fleet_api.client("tenant-a") as client:
        report = client.get("/v1/usage", params={"from": today, "to": today}).json()
    total = report["total"]
    assert report["tenant"] == "tenant-a" and report["days"][0]["day"] == today
    assert total["jobs_by_state"].get("succeeded", 0) >= JOBS
    expected_cpu = sum(j["usage"]["cpu_seconds_total"] for j in jobs)
    assert total["cpu_seconds"] >= expected_cpu - 0.01 * JOBS
    assert total["bytes_stored"] >= sum(j["usage"]["bytes_stored"] for j in jobs)
    with fleet_api.client(IDLE_TENANT) as other:  # tenant isolation: a's jobs are not counted
        assert other.get("/v1/usage", params={"from": today, "to": today}).json()["total"]["jobs"] == 0
        assert other.get(f"/v1/batches/{fleet['batch']['id']}/events").status_code == 404
    with fleet_api.client("tenant-a") as client:
        assert client.get("/v1/usage", params={"from": today, "to": "2000-01-01"}).status_code == 422
