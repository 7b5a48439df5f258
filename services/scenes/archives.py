"""Safe extraction of uploaded image archives (zip, tar, tar.gz/bz2/xz).

An archive from the internet is hostile until proven otherwise. Before a byte is written every
member is checked: a relative path with no ``..`` part, no absolute or drive-letter path, a regular
file or a folder only (no symlinks, hardlinks, devices), at most `max_members` members, and the
sum of the *declared* sizes under `max_bytes`. Declared sizes can lie (a crafted zip header), so
the bytes actually produced while extracting are counted too and extraction stops the moment they
pass the limit: a decompression bomb costs at most `max_bytes` of disk.

Members the filesystem could not hold are refused before extraction too, by name: a path component
longer than NAME_MAX (255 bytes), a path deeper than `MAX_MEMBER_DEPTH` parts or longer than
`MAX_MEMBER_PATH_BYTES`, a name that is both a file and a folder, a name that is not UTF-8 or has
control characters, a zip compression method Python cannot decode. Whatever else goes wrong while
reading or writing a member (a corrupt stream, a CRC mismatch, ...) is an InputError too
(`input_boundary`), so an archive never answers 500.
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

from bayesian_fields_core.errors import InputError, input_boundary

_CHUNK = 1 << 20
NAME_MAX = 255
"""Longest path component, in bytes, that Linux filesystems accept."""
MAX_MEMBER_DEPTH = 32
"""Most path components a member may have (image archives are one or two folders deep)."""
MAX_MEMBER_PATH_BYTES = 1024
"""Longest member path, in bytes (well inside PATH_MAX once joined to the scene folder)."""
_ZIP_METHODS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate", zipfile.ZIP_BZIP2: "bzip2",
                zipfile.ZIP_LZMA: "lzma"}  # fmt: skip
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
    if any(ord(c) < 32 or ord(c) == 127 for c in name):
        raise InputError(f"archive member {name!r} has a control character in its path", source=source)
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        raise InputError(f"archive member {name!r} has a name that is not UTF-8", source=source) from None
    path = PurePosixPath(name)
    if path.is_absolute() or (path.parts and ":" in path.parts[0]):
        raise InputError(f"archive member {name!r} has an absolute path", source=source)
    if any(part == ".." for part in path.parts):
        raise InputError(f"archive member {name!r} has a '..' path component", source=source)
    parts = [p for p in path.parts if p not in ("", ".")]
    if not parts:
        raise InputError(f"archive member {name!r} has an empty path", source=source)
    shown = name if len(name) <= 80 else name[:60] + "..."
    long_part = next((p for p in parts if len(p.encode("utf-8")) > NAME_MAX), None)
    if long_part is not None:
        raise InputError(
            f"archive member {shown!r} has a path component of {len(long_part.encode('utf-8'))} bytes; "
            f"at most {NAME_MAX} are allowed",
            source=source,
        )
    if len(parts) > MAX_MEMBER_DEPTH or len("/".join(parts).encode("utf-8")) > MAX_MEMBER_PATH_BYTES:
        raise InputError(
            f"archive member {shown!r} is too deep ({len(parts)} components); at most "
            f"{MAX_MEMBER_DEPTH} components and {MAX_MEMBER_PATH_BYTES} bytes are allowed",
            source=source,
        )
    return PurePosixPath(*parts)


def _check_layout(paths: list[PurePosixPath], source: str) -> None:
    """Refuse a name used both as a file and as a folder, and a file listed twice."""
    files: set[PurePosixPath] = set()
    for rel in paths:
        if rel in files:
            raise InputError(f"archive has the file {str(rel)!r} twice", source=source)
        files.add(rel)
    for rel in paths:
        for parent in rel.parents:
            if parent in files:
                raise InputError(
                    f"archive member {str(parent)!r} is both a file and a folder (of {str(rel)!r})",
                    source=source,
                )


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
        if not info.is_dir() and info.compress_type not in _ZIP_METHODS:
            raise InputError(
                f"archive member {info.filename!r} uses zip compression method {info.compress_type}; "
                f"supported: {', '.join(_ZIP_METHODS.values())}",
                source=source,
            )
        members.append(_Member(info.filename, info.file_size, info.is_dir(), info))
    return members


def _tar_members(tf: tarfile.TarFile, source: str, max_members: int) -> list[_Member]:
    members: list[_Member] = []
    for info in tf:  # streams through the headers; content is not read yet
        if len(members) >= max_members:
            raise InputError(f"archive has more than {max_members} members", source=source)
        if info.issym():
            raise InputError(f"archive member {info.name!r} is a symbolic link", source=source)
        if info.islnk():
            raise InputError(f"archive member {info.name!r} is a hard link", source=source)
        if not (info.isreg() or info.isdir()):
            raise InputError(f"archive member {info.name!r} is not a regular file", source=source)
        members.append(_Member(info.name, info.size, info.isdir(), info))
    return members


@contextmanager
def _open_archive(path: Path, source: str, max_members: int) -> Iterator[tuple[list[_Member], object]]:
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
            members = _tar_members(tf, source, max_members)
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
    stripped, so archives of a folder and of its contents land the same way. Every failure is an
    InputError naming the archive (`source`) and, where known, the member.
    """
    with input_boundary(source, what="cannot extract the archive"):
        return _extract(path, dest, limits, source)


def _extract(path: Path, dest: Path, limits: ArchiveLimits, source: str) -> list[PurePosixPath]:
    with _open_archive(path, source, limits.max_members) as (members, handle):
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
        if strip:
            files = [(m, PurePosixPath(*p.parts[1:])) for m, p in files]
        _check_layout([p for _, p in files], source)
        written: list[PurePosixPath] = []
        budget = limits.max_bytes
        dest.mkdir(parents=True, exist_ok=True)
        for member, rel in files:
            target = dest.joinpath(*rel.parts)
            with input_boundary(source, what=f"cannot extract {member.name[:80]!r}"):
                target.parent.mkdir(parents=True, exist_ok=True)
                with _open_member(handle, member) as src, target.open("wb") as out:
                    budget = _copy_bounded(src, out, budget, limits.max_bytes, source)
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
