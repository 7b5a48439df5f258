"""The worker's scene cache on the real S3 server, with real concurrent processes: one download
shared by simultaneous leases, a new copy when an input object changes, LRU eviction by bytes
that never removes a copy in use, and the start-up clean-up of partial copies."""

from __future__ import annotations

import fcntl
import multiprocessing as mp
import os
import secrets
from pathlib import Path

import pytest

from bayesian_fields_service.storage.stores import tenant_store
from bayesian_fields_service.worker.scene_cache import SceneCache
from tests.integration.fixtures.s3_server import S3Server

pytestmark = pytest.mark.integration

SIZE = 50_000  # bytes per scene


def _scene(s3_server: S3Server, tenant: str) -> tuple[str, str]:
    """A scene's input (two objects, SIZE bytes) in the bucket; returns (scene id, prefix)."""
    scene_id = f"s_{secrets.token_hex(11)}"
    store = tenant_store(s3_server.store(), tenant)
    store.put_bytes(f"scenes/{scene_id}/input/splat.ply", os.urandom(SIZE - 100))
    store.put_bytes(f"scenes/{scene_id}/input/images/a.png", os.urandom(100))
    return scene_id, f"scenes/{scene_id}/"


def _lease_in_child(env: dict, root: str, tenant: str, scene_id: str, out: mp.Queue) -> None:
    from bayesian_fields_service.storage.s3_store import S3Credentials, S3Store

    store = S3Store(
        env["bucket"], endpoint_url=env["endpoint"], credentials=S3Credentials(env["id"], env["secret"])
    )
    cache = SceneCache(Path(root), 10 * SIZE)
    with cache.lease(tenant_store(store, tenant), tenant, scene_id, f"scenes/{scene_id}/") as folder:
        out.put((str(folder), folder.stat().st_ino, (folder / "splat.ply").stat().st_size))


def _s3_env(s3: S3Server) -> dict:
    return {
        "bucket": s3.bucket,
        "endpoint": s3.endpoint_url,
        "id": s3.access_key_id,
        "secret": s3.secret_access_key,
    }


def test_concurrent_processes_share_one_download(s3_server: S3Server, tmp_path: Path) -> None:
    scene_id, _ = _scene(s3_server, "tenant-a")
    # spawn, not fork: the test process holds threads (boto3, torch) by the time this runs in the
    # full suite, and a forked child can inherit one of their locks held, then hang forever.
    ctx = mp.get_context("spawn")
    out: mp.Queue = ctx.Queue()
    procs = [
        ctx.Process(
            target=_lease_in_child, args=(_s3_env(s3_server), str(tmp_path), "tenant-a", scene_id, out)
        )
        for _ in range(4)
    ]
    for p in procs:
        p.start()
    results = [out.get(timeout=120) for _ in procs]
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    assert len({r[0] for r in results}) == 1 and len({r[1] for r in results}) == 1  # one copy, one publish
    assert {r[2] for r in results} == {SIZE - 100}
    entries = [p for p in tmp_path.iterdir() if not p.name.startswith(".")]
    assert len(entries) == 1 and list((tmp_path / ".partial").iterdir()) == []


def test_changed_input_gets_a_new_copy(s3_server: S3Server, tmp_path: Path) -> None:
    scene_id, prefix = _scene(s3_server, "tenant-a")
    store = tenant_store(s3_server.store(), "tenant-a")
    cache = SceneCache(tmp_path, 10 * SIZE)
    with cache.lease(store, "tenant-a", scene_id, prefix) as first:
        pass
    store.put_bytes(prefix + "input/images/a.png", b"changed")
    with cache.lease(store, "tenant-a", scene_id, prefix) as second:
        assert (second / "images" / "a.png").read_bytes() == b"changed"
    assert first != second


def test_lru_eviction_by_bytes_skips_copies_in_use(s3_server: S3Server, tmp_path: Path) -> None:
    store = tenant_store(s3_server.store(), "tenant-a")
    cache = SceneCache(tmp_path, int(1.5 * SIZE))  # room for one scene
    (a, pa), (b, pb), (c, pc) = (_scene(s3_server, "tenant-a") for _ in range(3))
    with cache.lease(store, "tenant-a", a, pa) as folder_a:
        with cache.lease(store, "tenant-a", b, pb) as folder_b:
            # both in use: over the bound, nothing may go
            assert folder_a.is_dir() and folder_b.is_dir() and cache.total_bytes() > cache.max_bytes
        # b was released while a is still read: b is the one copy that may go, and it does
        assert (folder_a / "splat.ply").is_file() and not folder_b.exists()
    names = [e.name for e in cache.entries()]
    assert len(names) == 1 and a in names[0]
    with cache.lease(store, "tenant-a", c, pc):
        pass  # a is not in use now and least recently used: evicted to make room for c
    names = [e.name for e in cache.entries()]
    assert len(names) == 1 and c in names[0] and cache.total_bytes() <= cache.max_bytes


def test_clean_start_removes_only_abandoned_partials(tmp_path: Path) -> None:
    cache = SceneCache(tmp_path, 10 * SIZE)
    stale = tmp_path / ".partial" / "tenant-a--s_dead--v1.999.abcd"
    live = tmp_path / ".partial" / "tenant-a--s_busy--v1.998.abcd"
    for folder in (stale, live):
        (folder / "input").mkdir(parents=True)
        (folder / "input" / "splat.ply").write_bytes(b"x" * 100)
    unpublished = tmp_path / "tenant-a--s_half--v1"  # an entry without its size stamp
    unpublished.mkdir()
    fd = os.open(tmp_path / ".locks" / "tenant-a--s_busy--v1.lock", os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)  # a download in progress holds its entry's lock
    try:
        cache.clean_start()
    finally:
        os.close(fd)
    assert not stale.exists() and live.exists() and not unpublished.exists()


def test_least_recently_used_goes_first(s3_server: S3Server, tmp_path: Path) -> None:
    store = tenant_store(s3_server.store(), "tenant-a")
    cache = SceneCache(tmp_path, int(2.5 * SIZE))  # room for two scenes
    (a, pa), (b, pb), (c, pc) = (_scene(s3_server, "tenant-a") for _ in range(3))
    for scene_id, prefix in ((a, pa), (b, pb), (a, pa), (c, pc)):  # a used again after b
        with cache.lease(store, "tenant-a", scene_id, prefix):
            pass
    names = " ".join(e.name for e in cache.entries())
    assert a in names and c in names and b not in names
