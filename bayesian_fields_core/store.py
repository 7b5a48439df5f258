"""Artifact storage: the `Store` protocol every stage reads and writes through.

Stages never touch paths directly: they put and get named artifacts (keys such as
``scenes/<scene>/perception/frame_00012.npz``). `LocalStore` (a folder) is the embedded default;
the service provides an S3 implementation of the same protocol. Keeping stages behind this
interface is what lets the CLI and the Celery workers run the very same code and lets a job
resume from its last finished stage.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from .errors import InputError


class ArtifactNotFound(KeyError):
    """The key does not exist in the store."""


def validate_key(key: str) -> str:
    """Reject keys that could escape a namespace (absolute, '..', empty parts, backslashes)."""
    if not key or key.startswith("/") or key.endswith("/") or "\\" in key or "//" in key:
        raise InputError(f"invalid artifact key {key!r}")
    parts = key.split("/")
    if any(p in ("", ".", "..") for p in parts) or len(key) > 1024 or "\x00" in key:
        raise InputError(f"invalid artifact key {key!r}")
    return key


@runtime_checkable
class Store(Protocol):
    """Named-blob storage. Keys are '/'-separated relative paths."""

    def put_bytes(self, key: str, data: bytes) -> None: ...

    def get_bytes(self, key: str) -> bytes: ...

    def get_range(self, key: str, start: int, end: int) -> bytes:
        """Bytes [start, end) of an object (a ranged read)."""
        ...

    def put_file(self, key: str, path: Path) -> None: ...

    def get_file(self, key: str, path: Path) -> None: ...

    def exists(self, key: str) -> bool: ...

    def size(self, key: str) -> int: ...

    def list(self, prefix: str) -> list[str]: ...

    def delete(self, key: str) -> None: ...

    def delete_prefix(self, prefix: str) -> int: ...


class LocalStore:
    """A `Store` on a local folder. Writes are atomic (temp file + rename) so a crash mid-write
    never leaves a half artifact that a resumed stage would mistake for a finished one."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root).resolve()
        self.root.mkdir(parents=True, exist_ok=True)

    def __repr__(self) -> str:
        return f"LocalStore({str(self.root)!r})"

    def _path(self, key: str) -> Path:
        return self.root / validate_key(key)

    def put_bytes(self, key: str, data: bytes) -> None:
        path = self._path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-")
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def get_bytes(self, key: str) -> bytes:
        path = self._path(key)
        try:
            return path.read_bytes()
        except FileNotFoundError:
            raise ArtifactNotFound(key) from None

    def get_range(self, key: str, start: int, end: int) -> bytes:
        path = self._path(key)
        try:
            with path.open("rb") as fh:
                fh.seek(start)
                return fh.read(max(0, end - start))
        except FileNotFoundError:
            raise ArtifactNotFound(key) from None

    def put_file(self, key: str, path: Path) -> None:
        dest = self._path(key)
        dest.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=dest.parent, prefix=".tmp-")
        os.close(fd)
        try:
            shutil.copyfile(path, tmp)
            os.replace(tmp, dest)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def get_file(self, key: str, path: Path) -> None:
        src = self._path(key)
        if not src.is_file():
            raise ArtifactNotFound(key)
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, path)

    def exists(self, key: str) -> bool:
        return self._path(key).is_file()

    def size(self, key: str) -> int:
        path = self._path(key)
        if not path.is_file():
            raise ArtifactNotFound(key)
        return path.stat().st_size

    def list(self, prefix: str) -> list[str]:
        base = self.root / prefix if prefix else self.root
        search_root = base if base.is_dir() else base.parent
        if not search_root.exists():
            return []
        keys = []
        for p in search_root.rglob("*"):
            if p.is_file() and not p.name.startswith(".tmp-"):
                key = p.relative_to(self.root).as_posix()
                if key.startswith(prefix):
                    keys.append(key)
        return sorted(keys)

    def delete(self, key: str) -> None:
        self._path(key).unlink(missing_ok=True)

    def delete_prefix(self, prefix: str) -> int:
        keys = self.list(prefix)
        for key in keys:
            self.delete(key)
        return len(keys)


class PrefixedStore:
    """A view of another store under a fixed key prefix (used for tenant namespacing)."""

    def __init__(self, inner: Store, prefix: str) -> None:
        self.inner = inner
        self.prefix = validate_key(prefix.strip("/")) + "/"

    def _k(self, key: str) -> str:
        return self.prefix + validate_key(key)

    def put_bytes(self, key: str, data: bytes) -> None:
        self.inner.put_bytes(self._k(key), data)

    def get_bytes(self, key: str) -> bytes:
        return self.inner.get_bytes(self._k(key))

    def get_range(self, key: str, start: int, end: int) -> bytes:
        return self.inner.get_range(self._k(key), start, end)

    def put_file(self, key: str, path: Path) -> None:
        self.inner.put_file(self._k(key), path)

    def get_file(self, key: str, path: Path) -> None:
        self.inner.get_file(self._k(key), path)

    def exists(self, key: str) -> bool:
        return self.inner.exists(self._k(key))

    def size(self, key: str) -> int:
        return self.inner.size(self._k(key))

    def list(self, prefix: str) -> list[str]:
        n = len(self.prefix)
        return [k[n:] for k in self.inner.list(self.prefix + prefix)]

    def delete(self, key: str) -> None:
        self.inner.delete(self._k(key))

    def delete_prefix(self, prefix: str) -> int:
        return self.inner.delete_prefix(self.prefix + prefix)


# ---- typed helpers: every artifact is JSON or an .npz without pickled objects -------------


def put_json(store: Store, key: str, obj: Any) -> None:
    store.put_bytes(key, json.dumps(obj, indent=2, sort_keys=True).encode())


def get_json(store: Store, key: str) -> Any:
    return json.loads(store.get_bytes(key))


def put_arrays(store: Store, key: str, compress: bool = True, **arrays: np.ndarray) -> None:
    """Write named arrays as an .npz (compressed by default)."""
    buf = io.BytesIO()
    (np.savez_compressed if compress else np.savez)(buf, **arrays)
    store.put_bytes(key, buf.getvalue())


def get_arrays(store: Store, key: str) -> dict[str, np.ndarray]:
    """Read an .npz written by `put_arrays`; object arrays are refused (allow_pickle=False)."""
    with np.load(io.BytesIO(store.get_bytes(key)), allow_pickle=False) as data:
        return {name: data[name] for name in data.files}


def iter_keys(store: Store, prefix: str) -> Iterator[str]:
    yield from store.list(prefix)
