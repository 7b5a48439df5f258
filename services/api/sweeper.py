"""Remove what an API process killed mid-request leaves behind, and nothing else.

An upload is received into a local temp folder, validated, then copied to the bucket, and only
then is its scene's row inserted; a presigned upload starts S3 multipart uploads before its row
is inserted. A SIGKILL (OOM killer, node loss) between those steps leaves things no API call can
see or delete:
- local temp folders ``bfields-upload-<pid>-*`` / ``bfields-complete-<pid>-*`` of a dead process;
- multipart uploads under ``tenants/<t>/scenes/<id>/staging/`` that no scene row lists in its
  ``pending_uploads`` (the row was never inserted);
- scene files under ``tenants/<t>/scenes/<id>/`` with no scene row (a single-request upload
  killed while it copied the scene into the bucket, or a completion that copied files after a
  delete had finished and whose process died before it could remove them);
- whatever is left of a scene whose row says ``deleting`` (`common.scenes`) and its multipart
  uploads: a delete that stopped after its mark. These go at once, whatever their age, and the
  row is purged: nothing may write a scene whose delete was acknowledged.

A scene folder that still holds an earlier release's record object and has no row is kept, with a
warning: it is a scene of a deployment upgraded without `bfields-service import-scenes`
(`common.scene_import`), not an orphan.

The sweep removes the others only when they are older than BFIELDS_ORPHAN_MAX_AGE_S (a temp
folder: since its last write, and never while its owner process is alive; an object: since its
newest write), so an upload in progress is never touched. Scenes that have a row, including those
still ``uploading``, are visible to their tenant (GET, DELETE) and are left alone. Every API
process sweeps its own temp folder at start and every BFIELDS_ORPHAN_SWEEP_INTERVAL_S; the bucket
part runs under a Redis lock, so one replica at a time does it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import redis

from bayesian_fields_service.common.scene_import import RECORD_NAME
from bayesian_fields_service.common.scenes import SceneStore
from bayesian_fields_service.common.storage import TENANTS_ROOT

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


def _scene_of(key: str) -> tuple[str, str] | None:
    """(tenant, scene id) of a key under ``tenants/<t>/scenes/<id>/``, else None."""
    parts = key.split("/")
    if len(parts) < 5 or parts[0] != TENANTS_ROOT or parts[2] != "scenes" or not parts[3]:
        return None
    return parts[1], parts[3]


def _scene_root(tenant: str, scene_id: str) -> str:
    return f"{TENANTS_ROOT}/{tenant}/scenes/{scene_id}/"


def sweep_bucket(
    store: Any, scenes: SceneStore, max_age_s: float, *, now: float | None = None
) -> BucketSweep:
    """Finish the deletes that stopped half-way, then abort multipart uploads and delete scene
    prefixes that no scene row names, when older than `max_age_s` (module docstring). `store` is
    the bucket's `S3Store` (needs list_prefixes, list_objects, list_multipart_uploads); `scenes`
    the scene rows."""
    now = time.time() if now is None else now
    out = BucketSweep()
    finished: set[str] = set()
    for scene in scenes.deleting_scenes():  # acknowledged deletes: at once, whatever the age
        root = _scene_root(scene.tenant, scene.id)
        for up in store.list_multipart_uploads(root):
            store.abort_multipart_upload(up.key, up.upload_id)
            out.aborted_uploads.append(up.key)
        store.delete_prefix(root)
        scenes.purge(scene.tenant, scene.id)
        out.deleted_prefixes.append(root)
        finished.add(root)

    old_uploads: dict[str, list[tuple[str, Any]]] = defaultdict(list)  # tenant -> (scene, upload)
    for up in store.list_multipart_uploads(f"{TENANTS_ROOT}/"):
        where = _scene_of(up.key)
        if where is not None and _age_s(up.initiated, now) >= max_age_s:
            old_uploads[where[0]].append((where[1], up))
    for tenant, uploads in old_uploads.items():
        listed = scenes.listed_uploads(tenant, sorted({scene_id for scene_id, _ in uploads}))
        for scene_id, up in uploads:
            if up.upload_id not in listed.get(scene_id, frozenset()):
                store.abort_multipart_upload(up.key, up.upload_id)
                out.aborted_uploads.append(up.key)

    for tenant_root in store.list_prefixes(f"{TENANTS_ROOT}/"):
        tenant = tenant_root.split("/")[1]
        roots = {r.rstrip("/").rpartition("/")[2]: r for r in store.list_prefixes(tenant_root + "scenes/")}
        known = scenes.listed_uploads(tenant, sorted(roots))
        for scene_id, root in roots.items():
            if scene_id in known or root in finished:
                continue
            objects = store.list_objects(root)
            if not objects or min(_age_s(o.last_modified, now) for o in objects) < max_age_s:
                continue  # still being written
            if any(o.key == root + RECORD_NAME for o in objects):
                log.warning("orphan sweep: %s has an earlier release's record and no row; kept "
                            "(run `bfields-service import-scenes`)", root)  # fmt: skip
                continue
            if scenes.listed_uploads(tenant, [scene_id]):
                continue  # its row was inserted meanwhile (an upload that copied slowly)
            store.delete_prefix(root)
            out.deleted_prefixes.append(root)
    return out


class Sweeper:
    """Runs both sweeps at start and every `interval_s` in a daemon thread of the API process."""

    def __init__(
        self,
        store: Any,
        scenes: SceneStore,
        client: redis.Redis,
        max_age_s: float,
        interval_s: float,
        temp_root: Path | None = None,
    ) -> None:
        self.store = store
        self.scenes = scenes
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
            return  # local backend: no multipart uploads, and uploads insert the row last
        lock = self.redis.lock("bf:orphan-sweep", timeout=max(60.0, self.interval_s), blocking_timeout=0)
        if not lock.acquire(blocking=False):
            return
        try:
            report = sweep_bucket(self.store, self.scenes, self.max_age_s)
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
