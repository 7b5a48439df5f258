"""No tenant starves another (issue 41, item 5; services/api/tenant_gate.py), on a real uvicorn over
raw sockets: a tenant's requests past its bound wait in its own queue, first in first out, while
another tenant is served; past the waiting bound the answer is 429 + Retry-After; a request with no
key or a bad one is no tenant's; a single well-behaved client never notices.

A "slow request" here is a real one: a POST whose body the test holds back after its first byte.
The API admits it and its route waits for the rest, so it holds one of the tenant's slots for as
long as the test likes. The API's own metrics (per tenant, with the stack's metrics token) count
the slots in flight and the requests waiting; no assertion depends on how fast the machine is,
only on what was answered before what.
"""

from __future__ import annotations

import re
import select
import socket
import time
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path

import httpx
import pytest

from tests.integration.fixtures.services import ApiServer
from tests.services.conftest import scene_form
from tests.services.support.lone_api import lone_api
from tests.services.support.problems import assert_problem

pytestmark = pytest.mark.integration

CONCURRENCY = 2
QUEUE = 3
STREAMS = 1
RETRY_AFTER_S = 7
WAIT_S = 30.0  # the longest any step may take on a loaded machine (a generous bound, not a timing)


@pytest.fixture(scope="module")
def fair_api(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ApiServer]:
    settings = {
        "BFIELDS_API_TENANT_CONCURRENCY": str(CONCURRENCY),
        "BFIELDS_API_TENANT_QUEUE": str(QUEUE),
        "BFIELDS_API_TENANT_STREAMS": str(STREAMS),
        "BFIELDS_EVENTS_POLL_S": "0.2",  # a closed stream is noticed (and its slot freed) soon
        "BFIELDS_RETRY_AFTER_S": str(RETRY_AFTER_S),
        "BFIELDS_METRICS_PER_TENANT": "true",
        "BFIELDS_API_BODY_TIMEOUT_S": "300",  # the held bodies below must not meet the body deadline
    }
    with lone_api(tmp_path_factory.mktemp("tenant-fairness"), settings) as api:
        yield api


class HeldPost:
    """``POST /v1/batches`` with a 2-byte body of which only the first byte is sent until `finish`."""

    def __init__(self, api: ApiServer, tenant: str) -> None:
        self.sock = socket.create_connection(("127.0.0.1", api.port), timeout=WAIT_S)
        head = (
            f"POST /v1/batches HTTP/1.1\r\nHost: 127.0.0.1\r\nX-API-Key: {api.keys[tenant]}\r\n"
            "Content-Type: application/json\r\nContent-Length: 2\r\n\r\n{"
        )
        self.sock.sendall(head.encode())
        self.answer = b""

    def finish(self) -> None:
        self.sock.sendall(b"}")

    def answered(self, wait_s: float = 0.0) -> bool:
        """Whether the status line has arrived (waiting up to `wait_s` for it)."""
        deadline = time.monotonic() + wait_s
        while b"\r\n" not in self.answer:
            ready, _, _ = select.select([self.sock], [], [], max(deadline - time.monotonic(), 0.0))
            if not ready:
                return False
            chunk = self.sock.recv(65536)
            if not chunk:
                return bool(self.answer)
            self.answer += chunk
        return True

    def status(self) -> int:
        assert self.answered(WAIT_S), "no answer"
        return int(self.answer.split(b" ", 2)[1])

    def close(self) -> None:
        self.sock.close()


def _gauge(api: ApiServer, name: str, tenant: str) -> float:
    found = re.search(rf'^{name}{{tenant="{tenant}"}} (\S+)$', api.metrics(), re.M)
    return float(found.group(1)) if found else 0.0


def _load(api: ApiServer, tenant: str, streams: bool = False) -> tuple[float, ...]:
    load = (
        _gauge(api, "bfields_api_tenant_requests_in_flight", tenant),
        _gauge(api, "bfields_api_tenant_requests_waiting", tenant),
    )
    return (*load, _gauge(api, "bfields_api_tenant_streams_open", tenant)) if streams else load


def _until_load(api: ApiServer, tenant: str, want: tuple[int, ...]) -> None:
    deadline = time.monotonic() + WAIT_S
    while (now := _load(api, tenant, streams=len(want) == 3)) != want:
        assert time.monotonic() < deadline, f"{tenant}: in flight / waiting {now}, expected {want}"
        time.sleep(0.05)


def test_a_busy_tenant_waits_in_its_own_queue_and_past_it_gets_429(fair_api: ApiServer) -> None:
    api = fair_api
    held = [HeldPost(api, "tenant-a") for _ in range(CONCURRENCY)]
    try:
        _until_load(api, "tenant-a", (CONCURRENCY, 0))
        waiting = []
        for _ in range(QUEUE):  # one at a time, so the queue's order is the order sent
            waiting.append(HeldPost(api, "tenant-a"))
            _until_load(api, "tenant-a", (CONCURRENCY, len(waiting)))
        assert not any(h.answered() for h in held + waiting)

        # past the waiting bound: 429 at once, with Retry-After, by either way of sending the key
        a_key = api.keys["tenant-a"]
        for headers in ({"X-API-Key": a_key}, {"Authorization": f"Bearer {a_key}"}):
            refused = httpx.get(f"{api.base_url}/v1/jobs", headers=headers, timeout=WAIT_S)
            assert refused.status_code == 429, refused.text
            assert refused.headers["Retry-After"] == str(RETRY_AFTER_S)
            assert (
                "BFIELDS_API_TENANT_CONCURRENCY" in assert_problem(refused, 429, "too-many-at-once")["detail"]
            )
            assert (
                refused.headers["RateLimit-Policy"]
                == f'"concurrency";q={CONCURRENCY + QUEUE};qu="concurrent-requests"'
            )
            assert refused.headers["RateLimit"] == f'"concurrency";r=0;t={RETRY_AFTER_S}'
        assert _gauge(api, "bfields_api_tenant_refused_total", "tenant-a") == 2

        # no key, a bad key: no tenant's request (401, never 429); health is never limited
        assert httpx.get(f"{api.base_url}/v1/jobs", timeout=WAIT_S).status_code == 401
        bad = httpx.get(f"{api.base_url}/v1/jobs", headers={"X-API-Key": "nobody"}, timeout=WAIT_S)
        assert bad.status_code == 401
        assert httpx.get(f"{api.base_url}/healthz", timeout=WAIT_S).status_code == 200

        # the other tenant is served while all of A's requests are still held or waiting
        with api.client("tenant-b") as b:
            assert b.get("/v1/jobs").status_code == 200
        assert not any(h.answered() for h in held + waiting)
        assert _load(api, "tenant-a") == (CONCURRENCY, QUEUE)

        # one of A's slots frees: the first waiting request takes it; the later ones, though their
        # bodies are complete, wait behind it (first in, first out)
        held[0].finish()
        assert held[0].status() == 422
        _until_load(api, "tenant-a", (CONCURRENCY, QUEUE - 1))
        for later in waiting[1:]:
            later.finish()
        time.sleep(1.0)
        assert not any(later.answered() for later in waiting[1:])
        waiting[0].finish()
        assert [w.status() for w in waiting] == [422] * QUEUE
        held[1].finish()
        assert held[1].status() == 422
        _until_load(api, "tenant-a", (0, 0))
    finally:
        for h in held + waiting:
            h.close()


def test_a_single_well_behaved_client_never_notices(fair_api: ApiServer) -> None:
    api = fair_api
    key = api.keys["tenant-b"]
    before = _gauge(api, "bfields_api_tenant_refused_total", "tenant-b")
    with httpx.Client(base_url=api.base_url, timeout=WAIT_S) as client:
        for i in range(4 * (CONCURRENCY + QUEUE)):  # one after another, either header
            headers = {"X-API-Key": key} if i % 2 else {"Authorization": f"Bearer {key}"}
            resp = client.get("/v1/jobs", headers=headers)
            assert resp.status_code == 200, resp.text
            assert "Retry-After" not in resp.headers
    assert _gauge(api, "bfields_api_tenant_refused_total", "tenant-b") == before == 0
    assert _load(api, "tenant-b") == (0, 0)


def test_a_stream_gives_its_slot_back_up_to_the_stream_bound(fair_api: ApiServer, scene_dir: Path) -> None:
    """An open event stream is counted among the tenant's streams, not its request slots; one past
    `STREAMS` keeps its slot, so the tenant's own requests wait until it ends."""
    api = fair_api
    with api.client("tenant-a") as a, ExitStack() as streams:
        upload = a.post("/v1/scenes", files=scene_form(scene_dir), data={"name": "fairness"})
        assert upload.status_code == 201, upload.text
        batch = a.post("/v1/batches", json={"items": [{"scene_id": upload.json()["id"], "tasks": ["cup"]}]})
        assert batch.status_code == 202, batch.text
        events = f"/v1/batches/{batch.json()['id']}/events"
        readers: list[Iterator[str]] = []  # kept: a line reader that is dropped closes its connection

        def open_stream() -> httpx.Response:
            resp = streams.enter_context(a.stream("GET", events))
            assert resp.status_code == 200
            readers.append(resp.iter_lines())
            assert any(line.startswith("event:") for line in readers[-1])  # its first event has arrived
            return resp

        open_stream()
        _until_load(api, "tenant-a", (0, 0, STREAMS))
        past_bound = open_stream()
        _until_load(api, "tenant-a", (1, 0, STREAMS))
        held = HeldPost(api, "tenant-a")  # the tenant's last free slot
        try:
            _until_load(api, "tenant-a", (CONCURRENCY, 0, STREAMS))
            waiting = HeldPost(api, "tenant-a")
            waiting.finish()
            _until_load(api, "tenant-a", (CONCURRENCY, 1, STREAMS))
            assert not waiting.answered(0.5)
            past_bound.close()  # the stream past the bound ends: its slot goes to the waiting request
            assert waiting.status() == 422
            held.finish()
            assert held.status() == 422
            _until_load(api, "tenant-a", (0, 0, STREAMS))
        finally:
            held.close()
            waiting.close()
        a.post(f"/v1/batches/{batch.json()['id']}/cancel")
