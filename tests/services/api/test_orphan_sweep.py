"""Orphan sweeping against a real uvicorn SIGKILLed mid-upload and the real S3 server.

What a killed API leaves: its upload temp folder (the request was streaming), multipart uploads
whose scene row was never inserted, and scene files copied before the row was (both made
here with the very S3 calls the upload routes make, as a kill between them leaves them). The
restarted API's start-up sweep (its temp folders) and the restarted control process's (the
bucket) remove those older than BFIELDS_ORPHAN_MAX_AGE_S, and leave
alone: a ready scene, a presigned upload in progress (its record lists the multipart upload),
orphans younger than the age, and a temp folder whose owner process is alive.

The stack has a bucket of its own: which scenes exist is its own database's rows, so with this
short age its sweep would take the session stack's scenes in a shared bucket for orphans.
"""

from __future__ import annotations

import dataclasses
import os
import secrets
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.integration.fixtures.s3_server import S3Server
from tests.services.conftest import SERVICE_ENV, scene_form
from tests.services.support.private_stack import PrivateStack, upload

pytestmark = [pytest.mark.integration]

MAX_AGE_S = 15
BOUNDARY = "bfields-test-boundary"


@pytest.fixture
def own_bucket(s3_server: S3Server) -> S3Server:
    """The session's S3 server seen through a new bucket of this test's own."""
    view = dataclasses.replace(s3_server, bucket=f"orphans-{secrets.token_hex(4)}")
    view.store().ensure_bucket()
    return view


@pytest.fixture
def stack(tmp_path: Path, own_bucket: S3Server, test_api_keys: dict[str, str]) -> Iterator[PrivateStack]:
    extra = {**SERVICE_ENV, "BFIELDS_ORPHAN_MAX_AGE_S": str(MAX_AGE_S)}
    stack = PrivateStack(tmp_path / "stack", own_bucket.env(), dict(test_api_keys), extra).start()
    yield stack
    stack.stop()


def _fake_scene_root() -> str:
    return f"tenants/tenant-a/scenes/s_{secrets.token_hex(11)}/"


def _make_orphans(store) -> tuple[str, str]:  # noqa: ANN001 - S3Store
    """A multipart upload with no scene row, and scene files with no scene row."""
    up_root, files_root = _fake_scene_root(), _fake_scene_root()
    store.create_multipart_upload(up_root + "staging/images/images.zip")
    store.put_bytes(files_root + "input/splat.ply", b"ply\n" + os.urandom(1000))
    store.put_bytes(files_root + "input/transforms.json", b"{}")
    return up_root, files_root


def _uploads(store) -> set[str]:  # noqa: ANN001
    return {u.key for u in store.list_multipart_uploads("tenants/")}


def _slow_upload(base_url: str, key: str, body: bytes, release: threading.Event) -> None:
    """POST a multipart body, stopping half way until `release` (the API is killed meanwhile)."""

    def chunks() -> Iterator[bytes]:
        yield body[: len(body) // 2]
        release.wait(60)
        yield body[len(body) // 2 :]

    headers = {"X-API-Key": key, "Content-Type": f"multipart/form-data; boundary={BOUNDARY}"}
    try:
        httpx.post(f"{base_url}/v1/scenes", content=chunks(), headers=headers, timeout=60)
    except httpx.HTTPError:
        pass  # the server died under it


def _multipart_body(form: list[tuple[str, tuple[str, bytes]]]) -> bytes:
    out = b""
    for field, (name, data) in form:
        out += (
            (
                f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="{field}"; filename="{name}"\r\n'
                "Content-Type: application/octet-stream\r\n\r\n"
            ).encode()
            + data
            + b"\r\n"
        )
    return out + f"--{BOUNDARY}--\r\n".encode()


def test_sweep_after_api_sigkill_mid_upload(
    stack: PrivateStack, own_bucket: S3Server, scene_dir: Path
) -> None:
    api = stack.api
    assert api is not None and api.process is not None
    store = own_bucket.store()
    with api.client("tenant-a") as client:
        ready_id = upload(client, scene_dir)
        spec = {"files": [{"field": "images", "name": "images.zip", "size": 1_000_000}]}
        plan = client.post("/v1/scenes/uploads", json=spec)
        assert plan.status_code == 201, plan.text
    uploading_id = plan.json()["scene_id"]
    old_upload, old_files = _make_orphans(store)
    t_old = time.monotonic()

    # an upload streaming into the API when it is SIGKILLed
    release = threading.Event()
    body = _multipart_body(scene_form(scene_dir))
    sender = threading.Thread(target=_slow_upload, args=(api.base_url, api.keys["tenant-a"], body, release))
    sender.start()
    api_pid = api.process.pid
    deadline = time.monotonic() + 30
    while not list(stack.temp_dir.glob(f"bfields-upload-{api_pid}-*/parts/part-*")):
        assert time.monotonic() < deadline, "the upload never reached the API's temp folder"
        time.sleep(0.05)
    api.process.kill()
    release.set()

    def control_log() -> str:
        assert api.controller is not None and api.controller.process is not None
        return api.controller.process.log_text()

    sender.join(30)
    killed = list(stack.temp_dir.glob(f"bfields-upload-{api_pid}-*"))
    assert len(killed) == 1  # what the kill left: nothing else would ever delete it

    # let the old orphans pass the age; then make young ones and a live process's temp folder
    time.sleep(max(0.0, MAX_AGE_S + 1 - (time.monotonic() - t_old)))
    young_upload, young_files = _make_orphans(store)
    live_tmp = stack.temp_dir / f"bfields-upload-{os.getpid()}-live"
    (live_tmp / "parts").mkdir(parents=True)
    (live_tmp / "parts" / "part-00000").write_bytes(b"x")
    os.utime(live_tmp / "parts" / "part-00000", (time.time() - 10 * MAX_AGE_S,) * 2)

    # the restarted API sweeps its temp folder at start; the bucket is the control process's to
    # sweep (one per deployment), which its leader does at start too
    assert api.controller is not None
    api.controller.stop()
    api.start()
    deadline = time.monotonic() + 60
    while (
        old_upload + "staging/images/images.zip" in _uploads(store)
        or store.list(old_files)
        or killed[0].exists()
    ):
        assert time.monotonic() < deadline, (
            f"not swept: uploads {_uploads(store)}, files {store.list(old_files)}, "
            f"temp {killed[0].exists()}\n{api.process.log_tail()}\n{control_log()}"
        )
        time.sleep(0.2)

    # live data and young orphans are intact
    assert young_upload + "staging/images/images.zip" in _uploads(store)
    assert store.list(young_files) == [young_files + "input/splat.ply", young_files + "input/transforms.json"]
    assert (live_tmp / "parts" / "part-00000").is_file()
    pending = f"tenants/tenant-a/scenes/{uploading_id}/staging/images/images.zip"
    assert pending in _uploads(store)
    with api.client("tenant-a") as client:
        assert client.get(f"/v1/scenes/{ready_id}").json()["state"] == "ready"
        assert client.get(f"/v1/scenes/{uploading_id}").json()["state"] == "uploading"
    assert store.list(f"tenants/tenant-a/scenes/{ready_id}/input/")
    log = control_log()
    assert "orphan sweep: aborted" in log and "control loop sweep failed" not in log, log
