"""Safe extraction of uploaded image archives (zip, tar, tar.gz/bz2/xz).

An archive from the internet is hostile until proven otherwise. Before a byte is written every
member is checked: a relative path with no ``..`` part, no absolute or drive-letter path, a regular
file or a folder only (no symlinks, hardlinks, devices), at most `max_members` members, and the
sum of the *declared* sizes under `max_bytes`. Declared sizes can lie (a crafted zip header), so
the bytes actually produced while extracting are counted too and extraction stops the moment they
pass the limit: a decompression bomb costs at most `max_bytes` of disk.
"""

from __future__ import annotations

import stat
import tarfile
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import IO

from bayesian_fields_core.errors import InputError

_CHUNK = 1 << 20
ARCHIVE_SUFFIXES = (".zip", ".tar", ".tar.gz", ".tgz", ".tar.bz2", ".tbz2", ".tar.xz", ".txz")


def is_archive_name(name: str) -> bool:
    return name.lower().endswith(ARCHIVE_SUFFIXES)


@dataclass(frozen=True)
class ArchiveLimits:
    max_members: int
    max_bytes: int


@dataclass(frozen=True)
class _Member:
    name: str
    size: int
    is_dir: bool
    opener: object  # zipfile.ZipInfo | tarfile.TarInfo


def safe_member_path(name: str, *, source: str) -> PurePosixPath:
    """The member's relative path, or InputError when it could escape the target folder."""
    if "\\" in name or "\x00" in name:
        raise InputError(f"archive member {name!r} has a backslash or NUL in its path", source=source)
    path = PurePosixPath(name)
    if path.is_absolute() or (path.parts and ":" in path.parts[0]):
        raise InputError(f"archive member {name!r} has an absolute path", source=source)
    if any(part == ".." for part in path.parts):
        raise InputError(f"archive member {name!r} has a '..' path component", source=source)
    parts = [p for p in path.parts if p not in ("", ".")]
    if not parts:
        raise InputError(f"archive member {name!r} has an empty path", source=source)
    return PurePosixPath(*parts)


def _zip_members(zf: zipfile.ZipFile, source: str) -> list[_Member]:
    members = []
    for info in zf.infolist():
        mode = info.external_attr >> 16
        if stat.S_ISLNK(mode):
            raise InputError(f"archive member {info.filename!r} is a symbolic link", source=source)
        if stat.S_IFMT(mode) and not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
            raise InputError(f"archive member {info.filename!r} is not a regular file", source=source)
        if info.flag_bits & 0x1:
            raise InputError(f"archive member {info.filename!r} is encrypted", source=source)
        members.append(_Member(info.filename, info.file_size, info.is_dir(), info))
    return members


def _tar_members(tf: tarfile.TarFile, source: str) -> list[_Member]:
    members = []
    for info in tf:  # streams through the headers; content is not read yet
        if info.issym():
            raise InputError(f"archive member {info.name!r} is a symbolic link", source=source)
        if info.islnk():
            raise InputError(f"archive member {info.name!r} is a hard link", source=source)
        if not (info.isreg() or info.isdir()):
            raise InputError(f"archive member {info.name!r} is not a regular file", source=source)
        members.append(_Member(info.name, info.size, info.isdir(), info))
    return members


@contextmanager
def _open_archive(path: Path, source: str) -> Iterator[tuple[list[_Member], object]]:
    if zipfile.is_zipfile(path):
        try:
            with zipfile.ZipFile(path) as zf:
                yield _zip_members(zf, source), zf
        except zipfile.BadZipFile as exc:
            raise InputError(f"corrupt zip archive: {exc}", source=source) from None
        return
    try:
        tf = tarfile.open(path, mode="r:*")
    except (tarfile.TarError, EOFError, OSError) as exc:
        raise InputError(f"not a readable zip or tar archive ({exc})", source=source) from None
    with tf:
        try:
            members = _tar_members(tf, source)
        except (tarfile.TarError, EOFError, OSError) as exc:
            raise InputError(f"corrupt tar archive: {exc}", source=source) from None
        yield members, tf


def _open_member(handle: object, member: _Member) -> IO[bytes]:
    if isinstance(handle, zipfile.ZipFile):
        return handle.open(member.opener)  # type: ignore[arg-type]
    stream = handle.extractfile(member.opener)  # type: ignore[attr-defined]
    assert stream is not None  # regular files only (checked)
    return stream


def extract_archive(path: Path, dest: Path, limits: ArchiveLimits, *, source: str) -> list[PurePosixPath]:
    """Extract `path` into `dest` after the checks above; returns the relative file paths written.

    A single top-level folder shared by every member (``images/a.png``, ``images/b.png``) is
    stripped, so archives of a folder and of its contents land the same way.
    """
    with _open_archive(path, source) as (members, handle):
        if len(members) > limits.max_members:
            raise InputError(
                f"archive has {len(members)} members; at most {limits.max_members} are allowed", source=source
            )
        declared = sum(m.size for m in members)
        if declared > limits.max_bytes:
            raise InputError(
                f"archive expands to {declared} bytes; at most {limits.max_bytes} are allowed "
                "(decompression bomb guard)",
                source=source,
            )
        files = [(m, safe_member_path(m.name, source=source)) for m in members if not m.is_dir]
        if not files:
            raise InputError("archive contains no files", source=source)
        tops = {p.parts[0] for _, p in files}
        strip = len(tops) == 1 and all(len(p.parts) > 1 for _, p in files)
        written: list[PurePosixPath] = []
        seen: set[PurePosixPath] = set()
        budget = limits.max_bytes
        dest.mkdir(parents=True, exist_ok=True)
        for member, rel in files:
            rel = PurePosixPath(*rel.parts[1:]) if strip else rel
            if rel in seen:
                raise InputError(f"archive has the file {str(rel)!r} twice", source=source)
            seen.add(rel)
            target = dest.joinpath(*rel.parts)
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                with _open_member(handle, member) as src, target.open("wb") as out:
                    budget = _copy_bounded(src, out, budget, limits.max_bytes, source)
            except (zipfile.BadZipFile, tarfile.TarError, EOFError, OSError) as exc:
                raise InputError(f"cannot extract {member.name!r}: {exc}", source=source) from None
            written.append(rel)
        return written


def _copy_bounded(src: IO[bytes], out: IO[bytes], budget: int, limit: int, source: str) -> int:
    """Copy until EOF, refusing to write more than `budget` bytes; returns the budget left."""
    while chunk := src.read(_CHUNK):
        budget -= len(chunk)
        if budget < 0:
            raise InputError(
                f"archive expands to more than {limit} bytes (decompression bomb guard)", source=source
            )
        out.write(chunk)
    return budget
