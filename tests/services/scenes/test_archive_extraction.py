"""Archive members that cannot be extracted are InputErrors naming the problem (issue 12, item 3):
a file and a folder of one name, a component past NAME_MAX, a very deep path, an unsupported
or corrupt compression stream, names that are not UTF-8; symlinks stay refused. No server."""

from __future__ import annotations

import io
import tarfile
import zipfile
from pathlib import Path

import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_service.scenes.archives import MAX_MEMBER_DEPTH, NAME_MAX, ArchiveLimits, extract_archive

LIMITS = ArchiveLimits(max_members=50, max_bytes=100_000)


def _zip(entries: dict[str, bytes], method: int = zipfile.ZIP_DEFLATED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", method) as zf:
        for name, data in entries.items():
            zf.writestr(name, data)
    return buf.getvalue()


def _tar(entries: dict[str, bytes], *, symlink: str | None = None) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w", format=tarfile.PAX_FORMAT) as tf:
        for name, data in entries.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tf.addfile(info, io.BytesIO(data))
        if symlink:
            info = tarfile.TarInfo(symlink)
            info.type, info.linkname = tarfile.SYMTYPE, "/etc/passwd"
            tf.addfile(info)
    return buf.getvalue()


def _refusal(tmp_path: Path, blob: bytes, name: str = "images.zip") -> str:
    archive = tmp_path / name
    archive.write_bytes(blob)
    with pytest.raises(InputError) as info:
        extract_archive(archive, tmp_path / "out", LIMITS, source=name)
    message = str(info.value)
    assert message.startswith(name) and str(tmp_path) not in message
    return message


@pytest.mark.parametrize("pack", [_zip, _tar])
def test_file_and_folder_of_the_same_name(tmp_path: Path, pack) -> None:
    assert "both a file and a folder" in _refusal(tmp_path, pack({"a/b": b"1", "a/b/c.png": b"2"}))


@pytest.mark.parametrize("pack", [_zip, _tar])
def test_component_longer_than_name_max(tmp_path: Path, pack) -> None:
    message = _refusal(tmp_path, pack({"x/" + "n" * (NAME_MAX + 1) + ".png": b"1", "y.png": b"2"}))
    assert f"at most {NAME_MAX}" in message
    # multi-byte characters: 128 characters but 256 bytes
    assert "path component" in _refusal(tmp_path, pack({"é" * 128: b"1"}))


@pytest.mark.parametrize("pack", [_zip, _tar])
def test_very_deep_path(tmp_path: Path, pack) -> None:
    deep = "/".join(["d"] * (MAX_MEMBER_DEPTH + 1)) + "/a.png"
    assert "too deep" in _refusal(tmp_path, pack({deep: b"1", "b.png": b"2"}))


def test_unsupported_compression_method(tmp_path: Path) -> None:
    blob = bytearray(_zip({"a.png": b"hello"}, zipfile.ZIP_STORED))
    # Compression method is at offset 8 of the local header and 10 of the central directory entry.
    blob[8:10] = (99).to_bytes(2, "little")
    central = blob.rfind(b"PK\x01\x02")
    blob[central + 10 : central + 12] = (99).to_bytes(2, "little")
    assert "compression method 99" in _refusal(tmp_path, bytes(blob))


def test_corrupt_deflate_stream(tmp_path: Path) -> None:
    blob = bytearray(_zip({"a.png": bytes(range(256)) * 40}))
    start = 30 + len("a.png")  # first member's data follows its local header
    blob[start : start + 40] = b"\xff" * 40
    assert "cannot extract" in _refusal(tmp_path, bytes(blob)) or "corrupt" in _refusal(tmp_path, bytes(blob))


def test_tar_member_name_that_is_not_utf8(tmp_path: Path) -> None:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w", format=tarfile.GNU_FORMAT, encoding="latin-1") as tf:
        info = tarfile.TarInfo("caf\xe9.png")
        info.size = 1
        tf.addfile(info, io.BytesIO(b"1"))
    assert "not UTF-8" in _refusal(tmp_path, buf.getvalue(), "images.tar")


def test_symlinks_are_refused_at_extraction(tmp_path: Path) -> None:
    assert "symbolic link" in _refusal(tmp_path, _tar({"a.png": b"1"}, symlink="b.png"), "images.tar")
    assert not (tmp_path / "out" / "a.png").exists()


def test_good_archive_still_extracts(tmp_path: Path) -> None:
    (tmp_path / "ok.zip").write_bytes(_zip({"images/a.png": b"1", "images/sub/b.png": b"2"}))
    written = extract_archive(tmp_path / "ok.zip", tmp_path / "out", LIMITS, source="ok.zip")
    assert sorted(map(str, written)) == ["a.png", "sub/b.png"]
