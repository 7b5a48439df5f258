"""S3Store against a real S3-compatible server (rclone serve s3), including presigned flows via httpx."""

from __future__ import annotations

import hashlib
import os
import threading
import time
import uuid
from collections import Counter
from pathlib import Path

import httpx
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import ArtifactNotFound, PrefixedStore, get_arrays, put_arrays
from bayesian_fields_service.storage.s3_store import (
    MIN_PART_BYTES,
    S3Credentials,
    S3Store,
    StorageAuthError,
    StorageError,
    plan_parts,
)
from bayesian_fields_service.storage.stores import tenant_store
from tests.integration.fixtures.processes import free_port
from tests.integration.fixtures.s3_server import S3Server

MiB = 1024**2


@pytest.fixture
def prefix() -> str:
    """A fresh key prefix per test: the bucket is shared by the session."""
    return f"t-{uuid.uuid4().hex[:12]}/"


def _count_calls(store: S3Store) -> Counter[str]:
    """Count the S3 operations the client really sends (botocore's own event hooks)."""
    calls: Counter[str] = Counter()

    def record(model, **_: object) -> None:  # noqa: ANN001
        calls[model.name] += 1

    store.client.meta.events.register("before-call.s3", record)
    return calls


def test_put_get_exists_size_delete(s3_store: S3Store, prefix: str) -> None:
    key = prefix + "a/b.bin"
    assert not s3_store.exists(key)
    s3_store.put_bytes(key, b"hello world")
    assert s3_store.exists(key)
    assert s3_store.get_bytes(key) == b"hello world"
    assert s3_store.size(key) == 11
    s3_store.put_bytes(key, b"v2")  # overwrite
    assert s3_store.get_bytes(key) == b"v2"
    s3_store.delete(key)
    assert not s3_store.exists(key)
    s3_store.delete(key)  # deleting a missing key is not an error (as on S3)


def test_missing_key_raises_artifact_not_found(s3_store: S3Store, prefix: str) -> None:
    for op in (s3_store.get_bytes, s3_store.size, lambda k: s3_store.get_range(k, 0, 4)):
        with pytest.raises(ArtifactNotFound):
            op(prefix + "nope")


def test_npz_roundtrip_through_typed_helpers(s3_store: S3Store, prefix: str) -> None:
    import numpy as np

    arr = np.arange(12, dtype=np.float32).reshape(3, 4)
    put_arrays(s3_store, prefix + "x.npz", a=arr)
    np.testing.assert_array_equal(get_arrays(s3_store, prefix + "x.npz")["a"], arr)


def test_ranged_reads(s3_store: S3Store, prefix: str) -> None:
    data = bytes(range(256)) * 4
    key = prefix + "r.bin"
    s3_store.put_bytes(key, data)
    assert s3_store.get_range(key, 10, 20) == data[10:20]
    assert s3_store.get_range(key, 1000, 5000) == data[1000:]  # clipped at the end, like a file
    assert s3_store.get_range(key, 2000, 2100) == b""  # wholly past the end
    assert s3_store.get_range(key, 5, 5) == b""
    with pytest.raises(InputError):
        s3_store.get_range(key, -1, 3)


def test_multipart_put_file_20mb(s3_server: S3Server, prefix: str, tmp_path: Path) -> None:
    store = s3_server.store(multipart_threshold=5 * MiB, multipart_chunksize=5 * MiB, max_concurrency=2)
    src = tmp_path / "big.bin"
    payload = os.urandom(20 * MiB + 123)
    src.write_bytes(payload)
    key = prefix + "big.bin"
    calls = _count_calls(store)
    store.put_file(key, src)
    assert store.size(key) == len(payload)
    assert calls["UploadPart"] == 5 and calls["CompleteMultipartUpload"] == 1 and calls["PutObject"] == 0
    dst = tmp_path / "out" / "big.bin"
    store.get_file(key, dst)
    assert hashlib.sha256(dst.read_bytes()).digest() == hashlib.sha256(payload).digest()
    assert store.get_range(key, 6 * MiB, 6 * MiB + 10) == payload[6 * MiB : 6 * MiB + 10]
    assert not list(dst.parent.glob(".tmp-*"))  # atomic download leaves no temp file


def test_large_put_bytes_uses_multipart(s3_server: S3Server, prefix: str) -> None:
    store = s3_server.store(multipart_threshold=5 * MiB, multipart_chunksize=5 * MiB)
    payload = os.urandom(11 * MiB)
    calls = _count_calls(store)
    store.put_bytes(prefix + "blob", payload)
    assert calls["UploadPart"] == 3
    assert store.get_bytes(prefix + "blob") == payload
    store.put_bytes(prefix + "small", b"s")
    assert calls["PutObject"] == 1


def test_put_file_missing_source(s3_store: S3Store, prefix: str, tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not a file"):
        s3_store.put_file(prefix + "x", tmp_path / "absent")


def test_presigned_get_and_put(s3_store: S3Store, prefix: str) -> None:
    s3_store.put_bytes(prefix + "doc.txt", b"presigned body")
    url = s3_store.presigned_get(prefix + "doc.txt", 60, filename="result.txt")
    resp = httpx.get(url)
    assert resp.status_code == 200 and resp.content == b"presigned body"
    # the signature covers the key: pointing the URL at another object is refused
    assert httpx.get(url.replace("doc.txt", "other.txt")).status_code == 403

    put_url = s3_store.presigned_put(prefix + "up.bin", 60)
    assert httpx.put(put_url, content=b"uploaded by a client").status_code == 200
    assert s3_store.get_bytes(prefix + "up.bin") == b"uploaded by a client"


def test_presigned_links_name_the_public_endpoint(
    s3_server: S3Server, s3_store: S3Store, prefix: str
) -> None:
    """Clients may reach the store at another address than the service (compose: the host's
    published port for the containers' minio:9000): links are signed for that address and work
    there, and the signature covers the host, so the service's own address would be refused."""
    assert s3_server.endpoint_url.startswith("http://127.0.0.1:")
    public = s3_server.endpoint_url.replace("127.0.0.1", "localhost")
    store = S3Store(
        s3_server.bucket,
        endpoint_url=s3_server.endpoint_url,
        public_endpoint_url=public,
        credentials=s3_server.credentials,
    )
    s3_store.put_bytes(prefix + "doc.txt", b"for a client elsewhere")
    url = store.presigned_get(prefix + "doc.txt", 60)
    assert url.startswith(public + "/")
    resp = httpx.get(url)
    assert resp.status_code == 200 and resp.content == b"for a client elsewhere"
    assert httpx.get(url.replace(public, s3_server.endpoint_url)).status_code == 403
    put_url = store.presigned_put(prefix + "up.bin", 60)
    assert put_url.startswith(public + "/")
    assert httpx.put(put_url, content=b"up").status_code == 200
    assert store.get_bytes(prefix + "up.bin") == b"up"


def test_presigned_multipart_upload(s3_store: S3Store, prefix: str) -> None:
    key = prefix + "scene.zip"
    payload = os.urandom(2 * MIN_PART_BYTES + 777)
    plan = plan_parts(len(payload), MIN_PART_BYTES)
    assert [p.part_number for p in plan] == [1, 2, 3]
    upload_id = s3_store.create_multipart_upload(key)
    reported = []
    for part in plan:
        url = s3_store.presigned_upload_part(key, upload_id, part.part_number, 60)
        resp = httpx.put(url, content=payload[part.start : part.end])
        assert resp.status_code == 200, resp.text
        reported.append({"PartNumber": part.part_number, "ETag": resp.headers["ETag"]})
    listed = s3_store.list_parts(key, upload_id)
    assert [p["PartNumber"] for p in listed] == [1, 2, 3]
    assert [p["ETag"] for p in listed] == [p["ETag"] for p in reported]
    assert not s3_store.exists(key)  # nothing visible before completion
    s3_store.complete_multipart_upload(key, upload_id, reported[::-1])  # order does not matter
    assert s3_store.get_bytes(key) == payload


def test_multipart_complete_from_server_list_and_abort(s3_store: S3Store, prefix: str) -> None:
    key = prefix + "m.bin"
    upload_id = s3_store.create_multipart_upload(key)
    httpx.put(s3_store.presigned_upload_part(key, upload_id, 1, 60), content=b"tail only").raise_for_status()
    s3_store.complete_multipart_upload(key, upload_id)  # parts=None: the server's own list
    assert s3_store.get_bytes(key) == b"tail only"

    upload_id = s3_store.create_multipart_upload(prefix + "aborted")
    s3_store.abort_multipart_upload(prefix + "aborted", upload_id)
    s3_store.abort_multipart_upload(prefix + "aborted", upload_id)  # idempotent
    assert not s3_store.exists(prefix + "aborted")
    with pytest.raises(InputError, match="no parts"):
        s3_store.complete_multipart_upload(
            prefix + "empty", s3_store.create_multipart_upload(prefix + "empty")
        )


def test_plan_parts_limits() -> None:
    with pytest.raises(InputError, match="minimum"):
        plan_parts(100, 1024)
    with pytest.raises(InputError, match="max 10000"):
        plan_parts(10_001 * MIN_PART_BYTES, MIN_PART_BYTES)
    with pytest.raises(InputError):
        plan_parts(0, MIN_PART_BYTES)
    parts = plan_parts(3 * MIN_PART_BYTES, MIN_PART_BYTES)
    assert parts[-1].end == 3 * MIN_PART_BYTES and len(parts) == 3


def test_presign_part_number_range(s3_store: S3Store, prefix: str) -> None:
    with pytest.raises(InputError):
        s3_store.presigned_upload_part(prefix + "x", "id", 0)
    with pytest.raises(InputError):
        s3_store.presigned_upload_part(prefix + "x", "id", 10_001)


def test_list_pagination_and_delete_prefix(s3_store: S3Store, prefix: str) -> None:
    keys = sorted(f"{prefix}d/{i:03d}" for i in range(23))
    for k in keys:
        s3_store.put_bytes(k, b"x")
    s3_store.put_bytes(prefix + "other", b"y")
    # page_size 5 forces 5 ListObjectsV2 round trips with continuation tokens
    pages = list(
        s3_store.client.get_paginator("list_objects_v2").paginate(
            Bucket=s3_store.bucket, Prefix=prefix + "d/", PaginationConfig={"PageSize": 5}
        )
    )
    assert len(pages) == 5
    assert s3_store.list(prefix + "d/", page_size=5) == keys
    assert s3_store.list(prefix) == [*keys, prefix + "other"]
    assert s3_store.delete_prefix(prefix + "d/") == 23
    assert s3_store.list(prefix) == [prefix + "other"]
    assert s3_store.delete_prefix(prefix + "d/") == 0


def test_invalid_keys_rejected(s3_store: S3Store) -> None:
    for bad in ("../x", "a/../b", "/abs", "a//b", "a\\b", ""):
        with pytest.raises(InputError):
            s3_store.put_bytes(bad, b"x")
    with pytest.raises(InputError):
        s3_store.list("../")


def test_wrong_credentials_raise_auth_error(s3_server: S3Server, prefix: str) -> None:
    # the raw protocol: a wrong secret gets HTTP 403 from the server
    bad = S3Store(
        s3_server.bucket,
        endpoint_url=s3_server.endpoint_url,
        credentials=S3Credentials(s3_server.access_key_id, "wrong-secret-" + "x" * 20),
        max_attempts=1,
    )
    resp = httpx.get(bad.presigned_get(prefix + "anything", 60))
    assert resp.status_code == 403
    with pytest.raises(StorageAuthError, match="BFIELDS_S3_SECRET_ACCESS_KEY"):
        bad.put_bytes(prefix + "x", b"x")
    with pytest.raises(StorageAuthError):
        bad.get_bytes(prefix + "x")


def test_tenant_isolation(s3_store: S3Store, prefix: str) -> None:
    a = tenant_store(s3_store, "tenant-a")
    b = tenant_store(s3_store, "tenant-b")
    a.put_bytes(prefix + "scene/input.ply", b"A's splat")
    assert s3_store.get_bytes(f"tenants/tenant-a/{prefix}scene/input.ply") == b"A's splat"
    assert a.list(prefix) == [prefix + "scene/input.ply"]
    assert b.list(prefix) == []
    assert not any("input.ply" in k for k in b.list(""))
    with pytest.raises(ArtifactNotFound):
        b.get_bytes(prefix + "scene/input.ply")
    for escape in ("../tenant-a/" + prefix + "scene/input.ply", "/tenants/tenant-a/x", "a/../../tenant-a/x"):
        with pytest.raises(InputError):
            b.get_bytes(escape)
    for bad_tenant in ("", "../x", "a/b", "x" * 65, "-lead"):
        with pytest.raises(InputError):
            tenant_store(s3_store, bad_tenant)
    assert isinstance(a, PrefixedStore)
    assert b.delete_prefix(prefix) == 0 and a.exists(prefix + "scene/input.ply")


@pytest.mark.slow
def test_retries_until_server_comes_up(tmp_path: Path) -> None:
    """A dropped connection is retried with backoff: the server starts while the client waits."""
    server = S3Server(tmp_path / "late", port=free_port())
    store = server.store(max_attempts=8, retry_base_delay_s=0.2, retry_max_delay_s=1.0, connect_timeout_s=1.0)
    starter = threading.Timer(0.8, server.start)
    starter.start()
    try:
        t0 = time.monotonic()
        with pytest.raises(ArtifactNotFound):  # reached the server (bucket now exists), key absent
            _wait_for_bucket_then_get(store)
        assert time.monotonic() - t0 >= 0.5
    finally:
        starter.join()
        server.stop()


def _wait_for_bucket_then_get(store: S3Store) -> bytes:
    deadline = time.monotonic() + 20
    while True:
        try:
            return store.get_bytes("missing-key")
        except StorageError as exc:  # server up, bucket not yet created by start(): try again
            if "does not exist" not in str(exc) or time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def test_unreachable_server_gives_clear_error() -> None:
    store = S3Store(
        "b-unreachable",
        endpoint_url=f"http://127.0.0.1:{free_port()}",
        credentials=S3Credentials("AKXXXXXXXXXXXXXX", "secret"),
        max_attempts=2,
        retry_base_delay_s=0.01,
        connect_timeout_s=0.5,
    )
    with pytest.raises(StorageError, match="unreachable after 2 attempts"):
        store.get_bytes("k")


def test_ensure_bucket_idempotent(s3_server: S3Server) -> None:
    store = S3Store("second-bucket", endpoint_url=s3_server.endpoint_url, credentials=s3_server.credentials)
    store.ensure_bucket()
    store.ensure_bucket()
    store.put_bytes("k", b"v")
    assert store.get_bytes("k") == b"v"
