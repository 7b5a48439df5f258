"""A finished job's result files as one zip, streamed: the /ui job page's "download all".

The zip is written while it is sent: each artifact is read from the store in `CHUNK`-byte ranged
reads (the same calls on the local folder and on S3) and deflated straight into the response, so
the API never holds a whole result (a recoloured export per task is a copy of the splat) in memory
or on disk. zipfile writes to a stream that cannot seek with a data descriptor after each member,
which every unzip tool reads. Compression level 1: the bulk is PLY, PNG and packed arrays that
deflate little, and the API's CPU is better spent answering.
"""

from __future__ import annotations

import io
import zipfile
from collections.abc import Iterator
from typing import Any

from bayesian_fields_core.job.store import Store

CHUNK = 1 << 20
"""Bytes read from the store per ranged read (and roughly per chunk sent)."""


class _Sink(io.RawIOBase):
    """The bytes zipfile writes, kept until the response takes them (it cannot seek)."""

    def __init__(self) -> None:
        self._parts: list[bytes] = []

    def writable(self) -> bool:
        return True

    def write(self, data: Any) -> int:  # any bytes-like object (typing.Buffer from 3.12)
        chunk = bytes(data)
        self._parts.append(chunk)
        return len(chunk)

    def take(self) -> bytes:
        out = b"".join(self._parts)
        self._parts.clear()
        return out


def zip_stream(store: Store, members: list[tuple[str, str]]) -> Iterator[bytes]:
    """The zip of `members` ((store key, name in the zip) pairs), in chunks as it is written."""
    sink = _Sink()
    with zipfile.ZipFile(sink, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
        for key, name in members:
            size = store.size(key)
            with archive.open(name, "w", force_zip64=size >= zipfile.ZIP64_LIMIT) as member:
                for start in range(0, size, CHUNK):
                    member.write(store.get_range(key, start, min(size, start + CHUNK)))
                    if chunk := sink.take():
                        yield chunk
            if chunk := sink.take():
                yield chunk
    yield sink.take()  # the central directory
