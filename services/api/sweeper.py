"""Remove what an API process killed mid-request leaves behind, and nothing else.

An upload is received into a local temp folder, validated, then copied to the bucket; a presigned
upload starts S3 multipart uploads before its scene record is written. A SIGKILL (OOM killer, node
loss) between those steps leaves things no API call can see or delete:
- local temp folders ``bfields-upload-<pid>-*`` / ``bfields-complete-<pid>-*`` of a dead process;
- multipart uploads under ``tenants/<t>/scenes/<id>/staging/`` that no scene record lists in its
  ``pending_uploads`` (the record was never written);
- scene files under ``tenants/<t>/scenes/<id>/`` with no ``scene.json`` (a single-request upload
  killed while it copied the scene into the bucket);
- whatever is left of a *deleted* scene (``tenants/<t>/tombstones/scenes/<id>`` exists: see
  `scene_lifecycle`), ``scene.json`` included, and its multipart uploads: a delete that failed
  half-way, or a completion that copied files after the delete listed them. These go at once,
  whatever their age: nothing may write a tombstoned scene.

The sweep removes each only when it is older than BFIELDS_ORPHAN_MAX_AGE_S (a temp folder: since
its last write, and never while its owner process is alive; an object: since its newest write),
so an upload in progress is never touched. Scenes that have a record, including those still
``uploading``, are visible to their tenant (GET, DELETE) and are left alone. Every API process
sweeps its own temp folder at start and every BFIELDS_ORPHAN_SWEEP_INTERVAL_S; the bucket part
runs under a Redis lock, so one replica at a time does it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
import threading
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import redis

from bayesian_fields_core.job.store import ArtifactNotFound, get_json

log = logging.getLogger(__name__)

TEMP_KINDS = ("upload", "complete")


def upload_workdir(kind: str) -> Path:
    """A new temp folder for one request, named after this process so the sweeper can tell a
    live owner from a dead one: ``<tmp>/bfields-<kind>-<pid>-<random>``."""
    return Path(tempfile.mkdtemp(prefix=f"bfields-{kind}-{os.getpid()}-"))


def _owner_pid(name: str) -> int | None:
    parts = name.split("-")  # bfields, kind, pid, random
    return int(parts[2]) if len(parts) >= 4 and parts[2].isdigit() else None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _last_write(folder: Path) -> float:
    newest = folder.lstat().st_mtime
    for dirpath, dirs, files in os.walk(folder):
        for name in (*dirs, *files):
            with contextlib.suppress(OSError):
                newest = max(newest, os.lstat(os.path.join(dirpath, name)).st_mtime)
    return newest


def sweep_temp(root: Path, max_age_s: float, *, now: float | None = None) -> list[str]:
    """Delete upload temp folders under `root` whose owner is not alive and whose last write is
    older than `max_age_s`; returns their names."""
    now = time.time() if now is None else now
    removed = []
    for kind in TEMP_KINDS:
        for folder in root.glob(f"bfields-{kind}-*"):
            if not folder.is_dir() or folder.is_symlink():
                continue
            pid = _owner_pid(folder.name)
            if pid is not None and pid != os.getpid() and _alive(pid):
                continue
            if pid == os.getpid():
                continue  # this process's own request is still running
            try:
                if now - _last_write(folder) < max_age_s:
                    continue
            except FileNotFoundError:
                continue
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder.name)
    return removed


@dataclass
class BucketSweep:
    """What one bucket sweep removed (full keys)."""

    aborted_uploads: list[str] = field(default_factory=list)
    deleted_prefixes: list[str] = field(default_factory=list)


def _age_s(stamp: Any, now: float) -> float:
    return now - stamp.timestamp()


def sweep_bucket(store: Any, max_age_s: float, *, now: float | None = None) -> BucketSweep:
    """Abort multipart uploads and delete scene prefixes that no scene record names, when older
    than `max_age_s`. `store` is the bucket's `S3Store` (needs list_prefixes, list_objects,
    list_multipart_uploads)."""
    now = time.time() if now is None else now
    out = BucketSweep()
    records: dict[str, dict | None] = {}
    tombstoned: dict[str, bool] = {}

    def deleted(scene_root: str) -> bool:  # tenants/<t>/scenes/<id>/ -> tenants/<t>/tombstones/...
        if scene_root not in tombstoned:
            tenant_root, _, scene_id = scene_root.rstrip("/").rpartition("/scenes/")
            tombstoned[scene_root] = store.exists(f"{tenant_root}/tombstones/scenes/{scene_id}")
        return tombstoned[scene_root]

    def record(scene_root: str) -> dict | None:  # scene_root = tenants/<t>/scenes/<id>/
        if scene_root not in records:
            try:
                records[scene_root] = get_json(store, scene_root + "scene.json")
            except ArtifactNotFound:
                records[scene_root] = None
        return records[scene_root]

    for up in store.list_multipart_uploads("tenants/"):
        parts = up.key.split("/")
        if len(parts) < 5 or parts[2] != "scenes":
            continue
        scene_root = "/".join(parts[:4]) + "/"
        if deleted(scene_root):
            store.abort_multipart_upload(up.key, up.upload_id)
            out.aborted_uploads.append(up.key)
            continue
        if _age_s(up.initiated, now) < max_age_s:
            continue
        rec = record(scene_root)
        listed = rec is not None and any(
            p.get("upload_id") == up.upload_id for p in rec.get("pending_uploads", [])
        )
        if not listed:
            store.abort_multipart_upload(up.key, up.upload_id)
            out.aborted_uploads.append(up.key)
    for tenant_root in store.list_prefixes("tenants/"):
        for scene_root in store.list_prefixes(tenant_root + "scenes/"):
            if deleted(scene_root):
                store.delete_prefix(scene_root)
                scene_id = scene_root.rstrip("/").rpartition("/")[2]
                store.delete(f"{tenant_root}index/scenes/{scene_id}")
                out.deleted_prefixes.append(scene_root)
                continue
            if record(scene_root) is not None:
                continue
            objects = store.list_objects(scene_root)
            if not objects or any(o.key.endswith("/scene.json") for o in objects):
                continue  # written meanwhile
            if min(_age_s(o.last_modified, now) for o in objects) < max_age_s:
                continue  # still being written
            store.delete_prefix(scene_root)
            out.deleted_prefixes.append(scene_root)
    return out


class Sweeper:
    """Runs both sweeps at start and every `interval_s` in a daemon thread of the API process."""

    def __init__(
        self,
        store: Any,
        client: redis.Redis,
        max_age_s: float,
        interval_s: float,
        temp_root: Path | None = None,
    ) -> None:
        self.store = store
        self.redis = client
        self.max_age_s = max_age_s
        self.interval_s = interval_s
        self.temp_root = temp_root or Path(tempfile.gettempdir())
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def sweep_once(self) -> None:
        removed = sweep_temp(self.temp_root, self.max_age_s)
        if removed:
            log.warning("orphan sweep: removed %d upload temp folders: %s", len(removed), removed)
        if not hasattr(self.store, "list_multipart_uploads"):
            return  # local backend: no multipart uploads, and uploads write the record last
        lock = self.redis.lock("bf:orphan-sweep", timeout=max(60.0, self.interval_s), blocking_timeout=0)
        if not lock.acquire(blocking=False):
            return
        try:
            report = sweep_bucket(self.store, self.max_age_s)
        finally:
            with contextlib.suppress(redis.RedisError):
                lock.release()
        if report.aborted_uploads or report.deleted_prefixes:
            log.warning(
                "orphan sweep: aborted %d multipart uploads %s, deleted %d staged scene prefixes %s",
                len(report.aborted_uploads),
                report.aborted_uploads,
                len(report.deleted_prefixes),
                report.deleted_prefixes,
            )

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                self.sweep_once()
            except Exception:  # keep sweeping whatever one pass hit (Redis or S3 down)
                log.exception("orphan sweep failed")
            self._stop.wait(self.interval_s)

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="bf-orphan-sweep", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()


def lifespan(
    make: Callable[[], Sweeper], also: Any = None
) -> Callable[[Any], contextlib.AbstractAsyncContextManager[None]]:
    """A FastAPI lifespan that runs the sweeper (and `also`, another object with start/stop, such
    as the dispatcher) while the app serves."""

    @contextlib.asynccontextmanager
    async def run(_: Any) -> AsyncIterator[None]:
        sweeper = make()
        sweeper.start()
        if also is not None:
            also.start()
        try:
            yield
        finally:
            if also is not None:
                also.stop()
            sweeper.stop()

    return run
