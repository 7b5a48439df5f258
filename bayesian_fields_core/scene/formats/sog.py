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
Checked against `splat-transform`'s own SOG -> PLY output. Why our own: gsply reads SOG only with
the `imagecodecs` extra; Pillow (already a dependency) decodes the lossless WebP.
"""

from __future__ import annotations

import io
import json
import logging
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats.common import gaussians, logit, require_count
from bayesian_fields_core.scene.types import Gaussians

log = logging.getLogger(__name__)
META = "meta.json"
MAX_META_BYTES = 16 << 20
MAX_IMAGE_PIXELS = 1 << 28


def _opener(path: Path) -> tuple[Callable[[str], bytes], str]:
    """(read member by name, label) for a .sog zip or a folder / meta.json path."""
    if path.is_dir() or path.name == META:
        folder = path if path.is_dir() else path.parent

        def read_file(name: str) -> bytes:
            target = (folder / name).resolve()
            if not target.is_relative_to(folder.resolve()) or "/" in name or "\\" in name:
                raise InputError(f"SOG names {name!r} outside its folder", source=str(path))
            if not target.is_file():
                raise InputError(f"SOG file {name!r} is missing", source=str(path))
            return target.read_bytes()

        return read_file, str(folder)
    try:
        archive = zipfile.ZipFile(path)
    except zipfile.BadZipFile:
        raise InputError("not a SOG file (not a zip archive)", source=str(path)) from None

    def read_member(name: str) -> bytes:
        try:
            info = archive.getinfo(name)
        except KeyError:
            raise InputError(f"SOG archive has no {name!r}", source=str(path)) from None
        if info.file_size > MAX_IMAGE_PIXELS * 4:
            raise InputError(f"SOG member {name!r} is too large", source=str(path))
        return archive.read(info)

    return read_member, str(path)


def sog_members(meta_path: Path) -> list[str]:
    """meta.json and every file it names (what a `.sog` zip of the folder holds)."""
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    names = [META]
    for value in meta.values() if isinstance(meta, dict) else []:
        if isinstance(value, dict) and isinstance(value.get("files"), list):
            names += [f for f in value["files"] if isinstance(f, str)]
    return names


def _image(read: Callable[[str], bytes], name: str, count: int, path: Path) -> np.ndarray:
    """(count, 4) uint8 RGBA of the first `count` pixels of a WebP."""
    try:
        with Image.open(io.BytesIO(read(name))) as img:
            if img.width * img.height > MAX_IMAGE_PIXELS:
                raise InputError(f"SOG image {name!r} is too large", source=str(path))
            pixels = np.asarray(img.convert("RGBA")).reshape(-1, 4)
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot decode SOG image {name!r} ({exc})", source=str(path)) from None
    if pixels.shape[0] < count:
        raise InputError(
            f"SOG image {name!r} has {pixels.shape[0]} pixels for {count} Gaussians", source=str(path)
        )
    return pixels[:count]


def _field(meta: dict[str, Any], key: str, path: Path) -> dict[str, Any]:
    value = meta.get(key)
    if not isinstance(value, dict) or not isinstance(value.get("files"), list) or not value["files"]:
        raise InputError(f"meta.json lacks a valid {key!r} entry", source=str(path))
    return value


def _codebook(entry: dict[str, Any], key: str, path: Path) -> np.ndarray:
    book = np.asarray(entry.get("codebook", []), dtype=np.float64)
    if book.shape != (256,) or not np.isfinite(book).all():
        raise InputError(f"meta.json {key} codebook must hold 256 finite numbers", source=str(path))
    return book.astype(np.float32)


def read_sog(path: Path, max_gaussians: int) -> Gaussians:
    """Decode a SOG bundle (zip or folder) into the INRIA parameterisation."""
    read, _ = _opener(path)
    raw = read(META)
    if len(raw) > MAX_META_BYTES:
        raise InputError("meta.json is too large", source=str(path))
    try:
        meta = json.loads(raw)
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"meta.json is not valid JSON ({exc})", source=str(path)) from None
    if not isinstance(meta, dict) or meta.get("version") != 2:
        raise InputError(
            f"SOG meta.json version {meta.get('version') if isinstance(meta, dict) else None!r}; "
            "only version 2 is read (re-export with a current splat-transform)",
            source=str(path),
        )
    n = meta.get("count")
    if not isinstance(n, int) or isinstance(n, bool):
        raise InputError("meta.json count must be an integer", source=str(path))
    require_count(n, max_gaussians, source=path)
    means_e, scales_e, quats_e, sh0_e = (_field(meta, k, path) for k in ("means", "scales", "quats", "sh0"))
    lo = np.asarray(means_e.get("mins"), dtype=np.float64).reshape(-1)
    hi = np.asarray(means_e.get("maxs"), dtype=np.float64).reshape(-1)
    if lo.shape != (3,) or hi.shape != (3,) or len(means_e["files"]) != 2:
        raise InputError("meta.json means needs 3 mins, 3 maxs and two files", source=str(path))
    low = _image(read, means_e["files"][0], n, path)[:, :3].astype(np.float64)
    up = _image(read, means_e["files"][1], n, path)[:, :3].astype(np.float64)
    norm = lo + (hi - lo) * ((up * 256.0 + low) / 65535.0)
    means = np.sign(norm) * np.expm1(np.abs(norm))
    scales = _codebook(scales_e, "scales", path)[_image(read, scales_e["files"][0], n, path)[:, :3]]
    q = _image(read, quats_e["files"][0], n, path)
    sh0 = _image(read, sh0_e["files"][0], n, path)
    dc = _codebook(sh0_e, "sh0", path)[sh0[:, :3]]
    if "shN" in meta:
        log.info("%s: SOG higher SH bands dropped (the pipeline renders depth, not colour)", path.name)
    return gaussians(
        means, scales, _quats(q, path), logit(sh0[:, 3].astype(np.float32) / 255.0), dc[:, None, :]
    )


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
