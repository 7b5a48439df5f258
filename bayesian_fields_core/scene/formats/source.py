"""A splat file opened for reading by row ranges: what every non-INRIA reader returns.

Why: reading a whole splat costs memory in proportion to what its header *declares*, and a
compressed format can declare millions of Gaussians in a few kilobytes (an all-zero SPZ payload
inflates a thousand times; a constant lossless WebP is a few bytes at any size). So each reader
first checks its header against its payload, then exposes the Gaussians as row ranges
(`SplatSource.rows`): the upload check walks them in bounded chunks (`formats.scan`), while the
pipeline reads them in one range. Compressed payloads are inflated once, through bounded reads,
into a `ByteStore`: in memory for the pipeline, or spilled to an unlinked temporary file beside
the upload for the check, so the check holds one chunk at a time whatever the file declares.
"""

from __future__ import annotations

import io
import tempfile
from abc import ABC, abstractmethod
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.types import Gaussians

READ_BYTES = 1 << 20
"""Bytes moved per bounded read / write when a payload is inflated or copied."""


class ByteStore:
    """Named byte blocks written once and then read by range, in memory or in a temporary file.

    `spill_dir` None keeps the bytes in memory (`io.BytesIO`); a folder writes them to an
    unlinked temporary file there (nothing to clean up if the process dies)."""

    def __init__(self, spill_dir: Path | None) -> None:
        self._file: BinaryIO = (
            io.BytesIO() if spill_dir is None else tempfile.TemporaryFile(dir=spill_dir)  # noqa: SIM115
        )
        self._blocks: dict[str, tuple[int, int]] = {}
        self._end = 0

    def write(self, name: str, chunks: Iterator[bytes], size: int, *, source: Path) -> None:
        """Store exactly `size` bytes of `chunks` as block `name`; InputError when they are fewer.
        Never takes more than `size`: a longer stream is cut there (its excess is not read)."""
        self._file.seek(self._end)
        written = 0
        for chunk in chunks:
            piece = chunk[: size - written]
            self._file.write(piece)
            written += len(piece)
            if written >= size:
                break
        if written < size:
            raise InputError(f"{name} data is truncated ({written} of {size} bytes)", source=str(source))
        self._blocks[name] = (self._end, size)
        self._end += size

    def read(self, name: str, start: int, length: int) -> bytes:
        """`length` bytes of block `name` from byte `start` (within the block)."""
        offset, size = self._blocks[name]
        if start < 0 or start + length > size:
            raise IndexError(f"{name}: bytes {start}..{start + length} outside a block of {size}")
        self._file.seek(offset + start)
        return self._file.read(length)

    def close(self) -> None:
        self._file.close()


def file_chunks(f: BinaryIO, length: int) -> Iterator[bytes]:
    """At most `length` bytes from `f`'s position, in reads of `READ_BYTES`."""
    left = length
    while left > 0:
        piece = f.read(min(READ_BYTES, left))
        if not piece:
            return
        left -= len(piece)
        yield piece


def read_exact(f: BinaryIO, offset: int, length: int, *, what: str, source: Path) -> bytes:
    """`length` bytes at `offset` of `f`, or InputError naming `what` as truncated."""
    f.seek(offset)
    data = f.read(length)
    if len(data) != length:
        raise InputError(f"{what} is truncated ({len(data)} of {length} bytes)", source=str(source))
    return data


class SplatSource(ABC):
    """An opened splat: its size, SH degree and Gaussians by row range, in the PLY's frame."""

    def __init__(self, path: Path, count: int, sh_degree: int) -> None:
        self.path = path
        self.count = count
        self.sh_degree = sh_degree

    @abstractmethod
    def rows(self, start: int, stop: int) -> Gaussians:
        """Gaussians `start` .. `stop` - 1 (file order), in the INRIA parameterisation."""

    def close(self) -> None:  # noqa: B027 - a source over an in-memory payload has nothing to release
        """Release open files and stored payloads."""

    def __enter__(self) -> SplatSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class FileWindow(io.RawIOBase):
    """`length` bytes of an open file from `offset`, as a readable stream that ends there.

    Why: a decompressor handed the whole file would read past a stream's declared size into
    the next one; a window makes the declared size the end of its input."""

    def __init__(self, f: BinaryIO, offset: int, length: int) -> None:
        super().__init__()
        self._f = f
        self._pos = offset
        self._left = length

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: bytearray | memoryview) -> int:  # type: ignore[override]
        n = min(len(buffer), self._left)
        if n <= 0:
            return 0
        self._f.seek(self._pos)
        data = self._f.read(n)
        buffer[: len(data)] = data
        self._pos += len(data)
        self._left -= len(data)
        return len(data)


class RecordTable:
    """`count` fixed-size records of `dtype` stored from byte `offset` of an open file, read by
    row range. Why: the uncompressed formats (.splat, compressed PLY, RGB PLY) declare a count
    the file must hold in full; checking the file's size against it first and then reading
    ranges means neither a short body nor a large one is ever read whole by the check."""

    def __init__(
        self, f: BinaryIO, offset: int, dtype: np.dtype, count: int, *, what: str, source: Path
    ) -> None:
        self._f = f
        self._offset = offset
        self.dtype = dtype
        self.count = count
        self._what = what
        self._source = source
        end = offset + dtype.itemsize * count
        size = f.seek(0, io.SEEK_END)
        if size < end:
            raise InputError(
                f"{what} is truncated: {count} rows need {dtype.itemsize * count} bytes, "
                f"the file holds {max(0, size - offset)}",
                source=str(source),
            )

    def read(self, start: int, stop: int) -> np.ndarray:
        """Records `start` .. `stop` - 1 as a structured array, shape (stop - start,)."""
        n = max(0, min(stop, self.count) - start)
        raw = read_exact(
            self._f,
            self._offset + start * self.dtype.itemsize,
            n * self.dtype.itemsize,
            what=self._what,
            source=self._source,
        )
        return np.frombuffer(raw, dtype=self.dtype, count=n)
