"""One local copy of each scene per worker host, shared by every stage and pool process, bounded.

Why: a stage reads the scene (splat, cameras, images) from files, so a worker on object storage
must download it first. Downloading it into a fresh folder per stage filled worker disks (hundreds
of copies after a few hundred jobs). Here a scene lands once in ``<root>/<entry>/`` where the entry
name is derived from the tenant, the scene id and a *content version* (a hash of the listing of the
scene's input keys with their sizes and ETags), so a changed input can never be served from an old
copy and an unchanged one is never fetched twice.

Concurrency (prefork children and several workers on one host share the folder):
- every entry has a lock file ``<root>/.locks/<entry>.lock`` (``flock``, released by the kernel when
  a process dies, so a SIGKILLed holder never wedges it);
- a download runs under the exclusive lock into ``<root>/.partial/<entry>.<pid>.<random>/`` and is
  published with one atomic ``rename``: a reader sees a complete copy or none;
- a stage holds the shared lock while it reads the copy (`SceneCache.lease`), and eviction only
  deletes entries whose exclusive lock it gets without waiting, so a copy in use is never removed.

Bound: after each new copy, entries are evicted least recently used first (by the mtime of their
``.used`` stamp, touched on every lease) until the total is at most ``max_bytes``
(BFIELDS_WORKER_SCENE_CACHE_MAX_BYTES). A single scene larger than the bound is still served, and
evicted as soon as it is no longer in use. `SceneCache.clean_start` (worker start) removes partial
downloads whose owner is gone and enforces the bound.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import logging
import os
import secrets
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import LocalStore, PrefixedStore, Store

log = logging.getLogger(__name__)

_USED = ".used"  # touched on every lease: its mtime orders the LRU
_SIZE = ".bytes"  # the entry's size in bytes, written once when the entry is published


@dataclass(frozen=True)
class ObjectEntry:
    """One object of a scene's input listing: key (relative to the input prefix), size, ETag."""

    name: str
    size: int
    etag: str = ""


def list_input(store: Store, prefix: str) -> list[ObjectEntry]:
    """The objects under `prefix` with their sizes (one LIST per 1000 keys on S3; a HEAD per key
    only on stores without a sized listing)."""
    inner: Any = store
    outer = ""
    while isinstance(inner, PrefixedStore):  # list on the bucket itself: one call returns sizes
        outer = inner.prefix + outer
        inner = inner.inner
    if hasattr(inner, "list_objects"):
        full = outer + prefix
        return [ObjectEntry(info.key[len(full) :], info.size, info.etag) for info in inner.list_objects(full)]
    return [ObjectEntry(key[len(prefix) :], store.size(key)) for key in store.list(prefix)]


def content_version(entries: list[ObjectEntry]) -> str:
    """A hash of the listing (names, sizes, ETags): changes whenever any input object does."""
    h = hashlib.sha256()
    for e in sorted(entries, key=lambda e: e.name):
        h.update(f"{e.name}\0{e.size}\0{e.etag}\n".encode())
    return h.hexdigest()[:16]


def local_folder(store: Store, prefix: str) -> Path | None:
    """The folder holding `prefix` when `store` is (a prefixed view of) a `LocalStore`: nothing to
    copy then."""
    inner: Any = store
    outer = ""
    while isinstance(inner, PrefixedStore):
        outer = inner.prefix + outer
        inner = inner.inner
    if isinstance(inner, LocalStore):
        folder = inner.root / (outer + prefix)
        return folder if folder.is_dir() else None
    return None


def _tree_bytes(folder: Path) -> int:
    total = 0
    for dirpath, _, files in os.walk(folder):
        for name in files:
            with contextlib.suppress(OSError):
                total += os.lstat(os.path.join(dirpath, name)).st_size
    return total


def _stamp(path: Path) -> None:
    """Set the file's mtime to now at full clock resolution: ``utime(path, None)`` takes the
    kernel's coarse clock (a tick of several ms), so two leases in quick succession could tie and
    the LRU order would fall to the entry names."""
    now = time.time_ns()
    os.utime(path, ns=(now, now))


class _FileLock:
    """An flock on one file; the kernel drops it when the process dies."""

    def __init__(self, path: Path) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)

    def lock(self, mode: int, *, wait: bool = True) -> bool:
        try:
            fcntl.flock(self.fd, mode | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            return False
        return True

    def close(self) -> None:
        os.close(self.fd)  # releases the lock


class SceneCache:
    """The scene copies of one worker host under `root`, at most `max_bytes` in total."""

    def __init__(self, root: Path, max_bytes: int) -> None:
        self.root = Path(root)
        self.max_bytes = max_bytes
        self.locks = self.root / ".locks"
        self.partial = self.root / ".partial"
        for folder in (self.root, self.locks, self.partial):
            folder.mkdir(parents=True, exist_ok=True)

    @staticmethod
    def entry_name(tenant: str, scene_id: str, version: str) -> str:
        return f"{tenant}--{scene_id}--{version}"

    def entries(self) -> list[Path]:
        return [p for p in self.root.iterdir() if p.is_dir() and not p.name.startswith(".")]

    def total_bytes(self) -> int:
        return sum(self._entry_bytes(p) for p in self.entries())

    @staticmethod
    def _entry_bytes(entry: Path) -> int:
        try:
            return int((entry / _SIZE).read_text())
        except (OSError, ValueError):
            return _tree_bytes(entry)

    def _lock_for(self, name: str) -> _FileLock:
        return _FileLock(self.locks / f"{name}.lock")

    @contextlib.contextmanager
    def lease(self, store: Store, tenant: str, scene_id: str, scene_prefix: str) -> Iterator[Path]:
        """Yield the local folder of the scene's ``input/`` (downloaded once, shared, kept while
        the context is open: eviction skips it). The copy is ``<root>/<entry>/input/``."""
        prefix = scene_prefix + "input/"
        local = local_folder(store, prefix)
        if local is not None:
            yield local
            return
        listing = list_input(store, prefix)
        if not listing:
            raise InputError(f"no scene files for scene {scene_id!r}", source="scene")
        name = self.entry_name(tenant, scene_id, content_version(listing))
        entry = self.root / name
        lock = self._lock_for(name)
        try:
            while True:
                lock.lock(fcntl.LOCK_SH)
                if (entry / _SIZE).is_file():
                    break
                lock.lock(fcntl.LOCK_EX)  # (converts; the holder of a download finishes first)
                if not (entry / _SIZE).is_file():
                    self._download(store, prefix, listing, entry)
                    self.evict(keep=name)  # make room now, not after the stage
                # downgrade and re-check: an evictor may slip in between the two flock calls
            _stamp(entry / _USED)
            yield entry / "input"
        finally:
            lock.close()
            try:
                self.evict()
            except OSError as exc:  # housekeeping must never fail a stage
                log.warning("scene cache eviction failed: %s", exc)

    def _download(self, store: Store, prefix: str, listing: list[ObjectEntry], entry: Path) -> None:
        """Fetch every object into a partial folder, then publish it with one rename (caller holds
        the entry's exclusive lock)."""
        tmp = self.partial / f"{entry.name}.{os.getpid()}.{secrets.token_hex(4)}"
        try:
            for obj in listing:
                dest = tmp / "input" / obj.name
                store.get_file(prefix + obj.name, dest)
            (tmp / _SIZE).write_text(str(sum(o.size for o in listing)))
            (tmp / _USED).touch()
            shutil.rmtree(entry, ignore_errors=True)  # a half-deleted leftover of an eviction
            os.rename(tmp, entry)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        log.info("scene cache: fetched %s (%d files)", entry.name, len(listing))

    def evict(self, keep: str | None = None) -> list[str]:
        """Delete least recently used entries not in use until the total fits `max_bytes`; returns
        the names removed."""
        entries = []
        for entry in self.entries():
            try:
                used = (entry / _USED).stat().st_mtime
            except OSError:
                used = 0.0  # no stamp: a leftover, oldest of all
            entries.append((used, entry.name, entry, self._entry_bytes(entry)))
        total = sum(e[3] for e in entries)
        removed: list[str] = []
        for _, name, entry, size in sorted(entries):
            if total <= self.max_bytes:
                break
            if name == keep:
                continue
            lock = self._lock_for(name)
            try:
                if not lock.lock(fcntl.LOCK_EX, wait=False):
                    continue  # a stage is reading it (or it is being fetched)
                doomed = self.partial / f"{name}.evict.{os.getpid()}.{secrets.token_hex(4)}"
                try:
                    os.rename(entry, doomed)  # atomic: no reader ever sees a half-deleted copy
                except OSError:
                    continue
                shutil.rmtree(doomed, ignore_errors=True)
            finally:
                lock.close()
            total -= size
            removed.append(name)
            log.info("scene cache: evicted %s (%d bytes)", name, size)
        if total > self.max_bytes:
            log.warning(
                "scene cache holds %d bytes (bound %d): every remaining copy is in use", total, self.max_bytes
            )
        return removed

    def clean_start(self) -> None:
        """Remove partial downloads whose owner is gone (a download holds its entry's exclusive
        lock, so a partial whose lock is free is stale), then enforce the bound."""
        for tmp in self.partial.iterdir():
            name = tmp.name.split(".", 1)[0]
            lock = self._lock_for(name)
            try:
                if lock.lock(fcntl.LOCK_EX, wait=False):
                    shutil.rmtree(tmp, ignore_errors=True)
                    log.info("scene cache: removed stale partial copy %s", tmp.name)
            finally:
                lock.close()
        for entry in self.entries():
            if not (entry / _SIZE).is_file():  # never published completely
                shutil.rmtree(entry, ignore_errors=True)
        self.evict()
