"""Request bodies have a read deadline (services/api/body_deadline.py), on a real uvicorn over raw
sockets: a client that drips its body gets 408 and a closed connection within the deadline (plus
slack), many at once hold nothing, and a normal upload and batch are not affected.

Issue 41: 1, 50 and 200 connections dripping a batch body (1 byte every 1-5 s) all stayed open
33-180 s.
"""

from __future__ import annotations

import json
import secrets
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.integration.fixtures.redis_server import RedisServer
from tests.integration.fixtures.s3_server import S3Server
from tests.integration.fixtures.services import ApiServer, build_service_env
from tests.services.conftest import scene_form
from tests.services.support.problems import check_problem, raw_problem

pytestmark = pytest.mark.integration

DEADLINE_S = 2.0
SLACK_S = 3.0


@pytest.fixture(scope="module")
def deadline_api(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ApiServer]:
    tmp = tmp_path_factory.mktemp("body-deadline")
    redis_server = RedisServer(tmp / "redis").start()
    s3 = S3Server(tmp / "s3").start()
    keys = {"tenant-d": "key-d-" + secrets.token_urlsafe(12)}
    # the 40 drippers below are one tenant's: with the fairness gate's default they would be cut 4
    # at a time (tenant_gate.py; test_tenant_fairness.py), while this module is about each one's deadline
    env = build_service_env(tmp / "env", redis_server.url(), s3.env(), keys,
                            {"BFIELDS_API_BODY_TIMEOUT_S": str(DEADLINE_S),
                             "BFIELDS_API_TENANT_CONCURRENCY": "100"})  # fmt: skip
    api = ApiServer(env=env, log_dir=tmp / "api", keys=keys, control=False).start()
    yield api
    api.stop()
    s3.stop()
    redis_server.stop()


def _drip(api: ApiServer, body: bytes, every_s: float, out: dict) -> None:
    """POST /v1/batches with `body` one byte every `every_s`, until the server answers or closes;
    `out` gets the answer's bytes, the seconds until the connection closed, and whether all of
    the body went out (it must not)."""
    started = time.monotonic()
    with socket.create_connection(("127.0.0.1", api.port), timeout=60) as sock:
        head = (
            f"POST /v1/batches HTTP/1.1\r\nHost: 127.0.0.1\r\nX-API-Key: {api.keys['tenant-d']}\r\n"
            f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n\r\n"
        )
        sock.sendall(head.encode())
        sock.setblocking(False)
        answer, sent, closed = b"", 0, False
        while not closed and time.monotonic() - started < 60:
            if sent < len(body):
                try:
                    sock.send(body[sent : sent + 1])
                    sent += 1
                except OSError:
                    pass  # the server closed its side: read what it said
            wait_until = time.monotonic() + every_s
            while time.monotonic() < wait_until:
                try:
                    chunk = sock.recv(65536)
                except BlockingIOError:
                    time.sleep(0.02)
                    continue
                except OSError:
                    closed = True
                    break
                if not chunk:
                    closed = True
                    break
                answer += chunk
    out.update(answer=answer, closed_after_s=time.monotonic() - started, all_sent=sent == len(body),
               closed=closed)  # fmt: skip


def _status(answer: bytes) -> int:
    return int(answer.split(b" ", 2)[1]) if answer.startswith(b"HTTP/1.1 ") else 0


def test_a_dripped_body_gets_408_and_a_closed_connection_within_the_deadline(deadline_api: ApiServer) -> None:
    body = json.dumps(
        {"scene_ids": ["s_0000000000000000000000"], "task_lists": [["a slow one"]] * 20}
    ).encode()
    out: dict = {}
    _drip(deadline_api, body, 1.0, out)
    assert out["closed"] and not out["all_sent"], out
    assert _status(out["answer"]) == 408, out["answer"][:300]
    assert b"connection: close" in out["answer"].lower()
    assert b"BFIELDS_API_BODY_TIMEOUT_S" in out["answer"]
    assert out["closed_after_s"] < DEADLINE_S + SLACK_S, out["closed_after_s"]
    check_problem(*raw_problem(out["answer"]), 408, "request-timeout", "/v1/batches")  # the one error body


def test_many_dripping_clients_are_all_cut_and_others_are_answered_meanwhile(deadline_api: ApiServer) -> None:
    body = b'{"scene_ids": [], "task_lists": []}' * 10
    outs: list[dict] = [{} for _ in range(40)]
    threads = [threading.Thread(target=_drip, args=(deadline_api, body, 1.5, out)) for out in outs]
    for t in threads:
        t.start()
    time.sleep(0.5)
    with deadline_api.client("tenant-d") as client:
        t0 = time.monotonic()
        assert client.get("/v1/jobs").status_code == 200
        assert time.monotonic() - t0 < DEADLINE_S
    for t in threads:
        t.join(60)
    assert [_status(o["answer"]) for o in outs] == [408] * len(outs)
    assert max(o["closed_after_s"] for o in outs) < DEADLINE_S + 2 * SLACK_S, [
        o["closed_after_s"] for o in outs
    ]


def test_a_body_that_stops_midway_is_cut_too(deadline_api: ApiServer) -> None:
    """Half a body at once, then nothing: cut after the per-chunk wait, not held open."""
    started = time.monotonic()
    with socket.create_connection(("127.0.0.1", deadline_api.port), timeout=30) as sock:
        sock.sendall(
            f"POST /v1/batches HTTP/1.1\r\nHost: x\r\nX-API-Key: {deadline_api.keys['tenant-d']}\r\n"
            "Content-Type: application/json\r\nContent-Length: 1000\r\n\r\n".encode()
            + b"{" * 500
        )
        answer = b""
        while chunk := sock.recv(65536):
            answer += chunk
    assert _status(answer) == 408, answer[:300]
    assert time.monotonic() - started < DEADLINE_S + SLACK_S


def test_a_normal_upload_and_batch_are_not_affected(deadline_api: ApiServer, scene_dir: Path) -> None:
    with deadline_api.client("tenant-d") as client:
        upload = client.post("/v1/scenes", files=scene_form(scene_dir), data={"name": "deadline"})
        assert upload.status_code == 201, upload.text
        scene_id = upload.json()["id"]
        batch = client.post("/v1/batches", json={"scene_ids": [scene_id], "task_lists": [["quick"]]})
        assert batch.status_code == 202, batch.text

        # a body sent in a few chunks, each well inside the deadline, is read whole
        def chunks() -> Iterator[bytes]:
            raw = json.dumps({"scene_ids": [scene_id], "task_lists": [["in chunks"]]}).encode()
            for i in range(0, len(raw), 16):
                time.sleep(0.1)
                yield raw[i : i + 16]

        chunked = client.post("/v1/batches", content=chunks(), headers={"Content-Type": "application/json"})
        assert chunked.status_code == 202, chunked.text
        for made in (batch, chunked):
            client.post(f"/v1/batches/{made.json()['id']}/cancel")
