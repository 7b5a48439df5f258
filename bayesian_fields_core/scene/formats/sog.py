"""PlayCanvas SOG (`.sog` zip, or a folder with `meta.json` and its WebP images), version 2.

Layout facts (meta.json, what `splat-transform` writes): `count`; `means` {mins, maxs, files:
[means_l.webp, means_u.webp]}: per Gaussian, per axis, a 16-bit value (upper byte in means_u,
lower in means_l) lerped between mins and maxs gives n, and the position is
sign(n) * (exp(|n|) - 1) (a log transform that keeps precision near the origin); `scales`
{codebook (256 log-scales), files: [scales.webp]}: the RGB bytes index the codebook per axis;
`quats` {files: [quats.webp]}: "smallest three" with RGB the three other components mapped
from [-1/sqrt2, 1/sqrt2] to bytes and alpha = 252 + the index of the largest (w, x, y, z order);
`sh0` {codebook, files: [sh0.webp]}: RGB index the DC codebook, alpha is the opacity byte.
Pixels run row-major over the image; the first `count` are the Gaussians. Higher SH bands
(`shN`, a palette of centroids) are dropped with a note: the pipeline renders only depth and
visibility from the splat, so view-dependent colour does not change its results.
Bounds, before anything is allocated: meta.json is validated as `sog_meta.SogMeta`; a zip's
member count comes from its end record and each member's size from its central directory, and
members are read through bounded streams; each image's size is read from its header and must
hold the count (at most `max(2 * count, count + IMAGE_SLACK)` pixels, never more than
`MAX_IMAGE_PIXELS`); images are decoded one at a time into a `ByteStore`.
Checked against `splat-transform`'s own SOG -> PLY output. Why our own: gsply reads SOG only with
the `imagecodecs` extra; Pillow (already a dependency) decodes the lossless WebP.
"""

from __future__ import annotations

import io
import logging
import lzma
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np
from PIL import Image

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats.common import gaussians, logit, require_count
from bayesian_fields_core.scene.formats.sog_meta import SogMeta
from bayesian_fields_core.scene.formats.source import ByteStore, SplatSource
from bayesian_fields_core.scene.formats.typed_json import MAX_JSON_BYTES, parse_json, typed
from bayesian_fields_core.scene.types import Gaussians

log = logging.getLogger(__name__)
META = "meta.json"
MAX_IMAGE_PIXELS = 1 << 25
"""Most pixels one SOG image may have (33.5 M: above the default 20 M Gaussian limit)."""
IMAGE_SLACK = 1 << 16
"""Pixels an image may have beyond its count (writers pad to a multiple-of-4 rectangle)."""
MAX_IMAGE_BYTES = MAX_IMAGE_PIXELS * 4 + (1 << 20)
"""Largest encoded image member read (never more than its raw RGBA plus a header's worth);
each image is also held to the raw RGBA of the most pixels its count allows, plus 1 MiB."""
MAX_MEMBERS = 64
"""Most entries a .sog zip may list (it holds meta.json and a handful of images)."""
ZIP_FAILURES = (
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    NotImplementedError,
    RuntimeError,
    OSError,
    EOFError,
    zlib.error,
    lzma.LZMAError,
    UnicodeDecodeError,
)
"""What `zipfile` raises on a damaged archive or member: a bad CRC or local header
(BadZipFile), an unknown or encrypted method (NotImplementedError, RuntimeError), offsets past
the file (OSError from seek), corrupt deflate / bzip2 / lzma data (zlib.error, OSError, LZMAError),
a name flagged UTF-8 that is not (UnicodeDecodeError, found by the reader fuzz target)."""
STRIP_ROWS = 256
"""Image rows converted to RGBA at a time while a decoded image is copied into the store."""


class _Members:
    """The files of a SOG bundle (zip or folder), each size-checked before it is read."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.folder: Path | None = None
        self.archive: zipfile.ZipFile | None = None
        if path.is_dir() or path.name == META:
            self.folder = path if path.is_dir() else path.parent
        else:
            _check_zip_directory(path)
            try:
                self.archive = zipfile.ZipFile(path)
            except ZIP_FAILURES as exc:
                raise InputError(
                    f"not a SOG file (not a readable zip archive: {exc})", source=str(path)
                ) from None

    def read(self, name: str, limit: int) -> bytes:
        """Member `name`, refused when it declares (or turns out) more than `limit` bytes."""
        if self.archive is None:
            return self._read_file(name, limit)
        try:
            info = self.archive.getinfo(name)
        except KeyError:
            raise InputError(f"SOG archive has no {name!r}", source=str(self.path)) from None
        if info.file_size > limit:
            raise InputError(
                f"SOG member {name!r} declares {info.file_size} bytes; at most {limit} are read",
                source=str(self.path),
            )
        try:
            with self.archive.open(info) as member:
                data = member.read(limit + 1)
        except ZIP_FAILURES as exc:
            raise InputError(f"SOG member {name!r} cannot be read ({exc})", source=str(self.path)) from None
        if len(data) > limit:
            raise InputError(f"SOG member {name!r} inflates past {limit} bytes", source=str(self.path))
        return data

    def _read_file(self, name: str, limit: int) -> bytes:
        assert self.folder is not None
        target = (self.folder / name).resolve()
        if not target.is_relative_to(self.folder.resolve()) or "/" in name or "\\" in name:
            raise InputError(f"SOG names {name!r} outside its folder", source=str(self.path))
        if not target.is_file():
            raise InputError(f"SOG file {name!r} is missing", source=str(self.path))
        if target.stat().st_size > limit:
            raise InputError(f"SOG file {name!r} is larger than {limit} bytes", source=str(self.path))
        with open(target, "rb") as f:
            return f.read(limit + 1)[:limit]

    def close(self) -> None:
        if self.archive is not None:
            self.archive.close()


def _check_zip_directory(path: Path) -> None:
    """Refuse a zip whose end record lists more than `MAX_MEMBERS` entries (or needs zip64)
    before `zipfile` builds an object per entry of its central directory."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        f.seek(max(0, size - (1 << 16) - 22))
        tail = f.read()
    at = tail.rfind(b"PK\x05\x06")
    if at < 0 or at + 22 > len(tail):
        raise InputError("not a SOG file (not a zip archive)", source=str(path))
    entries, directory = struct.unpack_from("<HI", tail, at + 10)
    if entries > MAX_MEMBERS or directory > MAX_MEMBERS * 1024:
        raise InputError(
            f"SOG zip lists {entries} entries ({directory} directory bytes); a SOG has at most {MAX_MEMBERS}",
            source=str(path),
        )


def read_meta(members: _Members, path: Path) -> SogMeta:
    """meta.json, bounded and validated (`sog_meta.SogMeta`)."""
    value = parse_json(members.read(META, MAX_JSON_BYTES), source=path, what=META)
    version = value.get("version") if isinstance(value, dict) else None
    if version != 2 or isinstance(version, bool):
        raise InputError(
            f"SOG meta.json version {version!r}; only version 2 is read (re-export with a current "
            "splat-transform)",
            source=str(path),
        )
    return typed(SogMeta, value, source=path, what=META)


def sog_members(meta_path: Path) -> list[str]:
    """meta.json and every file it names (what a `.sog` zip of the folder holds)."""
    with open(meta_path, "rb") as f:
        meta = parse_json(f.read(MAX_JSON_BYTES + 1), source=meta_path, what=META)
    names = [META]
    for value in meta.values() if isinstance(meta, dict) else []:
        if isinstance(value, dict) and isinstance(value.get("files"), list):
            names += [f for f in value["files"] if isinstance(f, str)]
    return names


def _store_image(members: _Members, block: str, name: str, count: int, store: ByteStore) -> None:
    """Decode image `name` (its size checked from its header first) and store the RGBA bytes of
    its first `count` pixels as `block`, copied in strips so no second full copy is made."""
    path = members.path
    cap = min(MAX_IMAGE_PIXELS, max(2 * count, count + IMAGE_SLACK))
    data = members.read(name, min(MAX_IMAGE_BYTES, cap * 4 + (1 << 20)))
    try:
        with Image.open(io.BytesIO(data)) as img:
            width, height = img.size
            if width * height < count or width * height > cap:
                raise InputError(
                    f"SOG image {name!r} is {width} x {height} pixels for {count} Gaussians "
                    f"(it must hold {count} and have at most {cap})",
                    source=str(path),
                )
            img.load()
            del data
            rows = -(-count // width)
            strips = (
                img.crop((0, y, width, min(rows, y + STRIP_ROWS))).convert("RGBA").tobytes()
                for y in range(0, rows, STRIP_ROWS)
            )
            store.write(block, strips, count * 4, source=path)
    except Image.DecompressionBombError as exc:
        raise InputError(f"SOG image {name!r} is too large ({exc})", source=str(path)) from None
    except (OSError, ValueError, SyntaxError) as exc:
        raise InputError(f"cannot decode SOG image {name!r} ({exc})", source=str(path)) from None


class SogSource(SplatSource):
    """A SOG bundle's five images stored as RGBA bytes, decoded by row range."""

    def __init__(self, path: Path, meta: SogMeta, store: ByteStore) -> None:
        super().__init__(path, meta.count, 0)
        self.meta, self.store = meta, store
        self.lo = np.asarray(meta.means.mins, np.float64)
        self.hi = np.asarray(meta.means.maxs, np.float64)
        self.scale_book = np.asarray(meta.scales.codebook, np.float32)
        self.dc_book = np.asarray(meta.sh0.codebook, np.float32)

    def _pixels(self, block: str, start: int, stop: int) -> np.ndarray:
        raw = self.store.read(block, start * 4, (stop - start) * 4)
        return np.frombuffer(raw, np.uint8).reshape(-1, 4)

    def rows(self, start: int, stop: int) -> Gaussians:
        low = self._pixels("means_l", start, stop)[:, :3].astype(np.float64)
        up = self._pixels("means_u", start, stop)[:, :3].astype(np.float64)
        norm = self.lo + (self.hi - self.lo) * ((up * 256.0 + low) / 65535.0)
        means = np.sign(norm) * np.expm1(np.abs(norm))
        scales = self.scale_book[self._pixels("scales", start, stop)[:, :3]]
        sh0 = self._pixels("sh0", start, stop)
        dc = self.dc_book[sh0[:, :3]]
        quats = _quats(self._pixels("quats", start, stop), self.path)
        return gaussians(means, scales, quats, logit(sh0[:, 3].astype(np.float32) / 255.0), dc[:, None, :])

    def close(self) -> None:
        self.store.close()


def open_sog(path: Path, max_gaussians: int, *, spill_dir: Path | None = None) -> SogSource:
    """Validate a SOG bundle's meta.json and images, then decode the images into a store."""
    members = _Members(path)
    store = ByteStore(spill_dir)
    try:
        meta = read_meta(members, path)
        require_count(meta.count, max_gaussians, source=path)
        for block, name in meta.images().items():
            _store_image(members, block, name, meta.count, store)
    except BaseException:
        store.close()
        raise
    finally:
        members.close()
    if meta.shN is not None:
        log.info("%s: SOG higher SH bands dropped (the pipeline renders depth, not colour)", path.name)
    return SogSource(path, meta, store)


def read_sog(path: Path, max_gaussians: int) -> Gaussians:
    """Decode a whole SOG bundle (zip or folder) into the INRIA parameterisation."""
    with open_sog(path, max_gaussians) as source:
        return source.rows(0, source.count)


def _quats(rgba: np.ndarray, path: Path) -> np.ndarray:
    largest = rgba[:, 3].astype(np.int64) - 252
    if ((largest < 0) | (largest > 3)).any():
        raise InputError("SOG quats alpha must be 252..255", source=str(path))
    abc = (rgba[:, :3].astype(np.float64) / 255.0 - 0.5) * np.sqrt(2.0)
    quats = np.empty((rgba.shape[0], 4), np.float64)
    for i in range(4):
        rows = largest == i
        quats[np.ix_(rows, [j for j in range(4) if j != i])] = abc[rows]
        quats[rows, i] = np.sqrt(np.clip(1.0 - (abc[rows] ** 2).sum(axis=1), 0.0, 1.0))
    return quats
