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
import zipfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from bayesian_fields_core.errors import InputError, InvariantError
from bayesian_fields_core.job.atomic import atomic_temp


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

    def local_path(self, key: str) -> Path:
        """The file that holds `key` (it may not exist): readers that stream a large artifact
        open it in place instead of reading its bytes into memory."""
        return self._path(key)

    def put_bytes(self, key: str, data: bytes) -> None:
        path = self._path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = atomic_temp(path.parent)
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
        fd, tmp = atomic_temp(dest.parent)
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
    # mypy matches **arrays against savez's `allow_pickle: bool` keyword; every value is an array
    (np.savez_compressed if compress else np.savez)(buf, **arrays)  # type: ignore[arg-type]
    store.put_bytes(key, buf.getvalue())


@dataclass(frozen=True)
class ArrayBlocks:
    """An array that `put_array_blocks` writes block by block and never holds whole.

    `shape` (rows first) and `dtype` of the whole array; `blocks`: arrays of shape
    `(rows_i, *shape[1:])` whose rows, in order, make it up (e.g. probabilities computed from the
    log-odds a few thousand rows at a time).
    """

    shape: tuple[int, ...]
    dtype: np.dtype
    blocks: Iterable[np.ndarray]


def _write_blocks(member: Any, name: str, array: ArrayBlocks) -> None:
    """An .npy member (format 1.0 header, C order) from `array.blocks`."""
    dtype = np.dtype(array.dtype)
    header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": array.shape}
    np.lib.format.write_array_header_1_0(member, header)
    rows = 0
    for block in array.blocks:
        block = np.ascontiguousarray(block, dtype=dtype)
        if block.ndim != len(array.shape) or block.shape[1:] != tuple(array.shape[1:]):
            raise InvariantError(
                f"block of shape {block.shape} in an array of shape {array.shape}", source=name
            )
        rows += block.shape[0]
        member.write(block.reshape(-1).view(np.uint8))  # the block's own buffer, no bytes copy
    if rows != array.shape[0]:
        raise InvariantError(f"blocks hold {rows} rows, the shape says {array.shape[0]}", source=name)


def _row_blocks(array: np.ndarray, block_bytes: int = 16 * 2**20) -> ArrayBlocks | np.ndarray:
    """A C-ordered array as blocks of rows (views, no copy); others as they are.

    numpy's own `write_array` copies a contiguous array whole (`tobytes`) when the target is not a
    plain file, which a zip member is.
    """
    if array.ndim == 0 or array.dtype.hasobject or not array.flags.c_contiguous:
        return array
    rows = max(1, block_bytes // max(1, array[:1].nbytes))
    blocks = (array[i : i + rows] for i in range(0, array.shape[0], rows))
    return ArrayBlocks(array.shape, array.dtype, blocks)


# Bytes per block of `put_array_blocks`: large enough that zlib and the file system see big
# writes, small enough that one block beside the caller's arrays is noise.
ARRAY_BLOCK_BYTES = 16 * 2**20


def put_array_blocks(
    store: Store,
    key: str,
    compress: bool = True,
    block_bytes: int = ARRAY_BLOCK_BYTES,
    **arrays: np.ndarray | ArrayBlocks,
) -> None:
    """`put_arrays` for large artifacts: the .npz goes straight to a file, one block at a time.

    `put_arrays` holds the whole archive in memory twice (the BytesIO and its `getvalue()` copy)
    beside the arrays themselves; for the fusion state of millions of Gaussians x 100 tasks that
    is gigabytes. Here memory holds only what the caller holds plus one block: the file is written
    beside the destination and renamed into place (LocalStore, atomic), or written to a temp file
    and uploaded with `put_file` (other stores). Plain arrays are written `block_bytes` of rows at
    a time. Read back with `get_arrays` like any .npz.
    """
    mode = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    if isinstance(store, LocalStore):
        dest = store.local_path(key)
        dest.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = atomic_temp(dest.parent)
    else:
        dest = None
        # a private scratch file in the system's temp folder, uploaded by `put_file`, never published
        fd, tmp_name = tempfile.mkstemp(prefix="bfields-npz-", suffix=".npz")
        tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, "wb") as fh, zipfile.ZipFile(fh, "w", compression=mode, allowZip64=True) as zf:
            for name, array in arrays.items():
                with zf.open(f"{name}.npy", "w", force_zip64=True) as member:
                    if not isinstance(array, ArrayBlocks):
                        array = _row_blocks(np.asarray(array), block_bytes)
                    if isinstance(array, ArrayBlocks):
                        _write_blocks(member, name, array)
                    else:
                        np.lib.format.write_array(member, array, allow_pickle=False)
        if dest is not None:
            os.replace(tmp, dest)
        else:
            store.put_file(key, tmp)
    finally:
        Path(tmp).unlink(missing_ok=True)


def get_arrays(store: Store, key: str) -> dict[str, np.ndarray]:
    """Read an .npz written by `put_arrays`; object arrays are refused (allow_pickle=False).

    A LocalStore file is decompressed in place (memory holds the arrays, not also the archive's
    bytes, which matters for the fusion state of a large scene); other stores go through bytes.
    """
    if isinstance(store, LocalStore):
        source: Any = store.local_path(key)
        if not source.is_file():
            raise ArtifactNotFound(key)
    else:
        source = io.BytesIO(store.get_bytes(key))
    with np.load(source, allow_pickle=False) as data:
        return {name: data[name] for name in data.files}


def iter_keys(store: Store, prefix: str) -> Iterator[str]:
    yield from store.list(prefix)
