"""Write a splat as PlayCanvas SOG version 2 (a `.sog` zip of `meta.json` and lossless WebP images).

No Python library writes SOG, so this is the inverse of the reader (`formats.sog`, whose docstring
has the layout, checked against splat-transform's own files): positions as 16-bit values of
sign(x) log(1 + |x|) lerped between per-axis bounds, split over `means_l` / `means_u`; log-scales
and the degree-0 SH colour as indices into one 256-entry codebook each; rotations as "smallest
three" bytes with alpha 252 + the index of the dropped (largest) component; opacity as the alpha
byte of `sh0`. Images are the squarest multiple-of-4 rectangle that holds the count, pixels
row-major, written by Pillow as lossless WebP with every RGB value kept (`exact`).

The codebooks are fitted as splat-transform fits them, by k-means (Lloyd's iterations in one
dimension, `CODEBOOK_ITERATIONS`, started from 256 quantiles); every value maps to its nearest
entry.
Higher SH bands (`shN`, a k-means palette in the format) are not written: the file holds the
degree-0 colour, as `.splat` does, and `export` says so.
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from pathlib import Path

import numpy as np
from PIL import Image

from bayesian_fields_core.scene.formats.sog_meta import CODEBOOK_SIZE
from bayesian_fields_core.scene.types import Gaussians

SOG_VERSION = 2
CODEBOOK_ITERATIONS = 10
"""Lloyd iterations of the 1-D k-means codebooks: the error stops falling after a few."""


def _image_size(count: int) -> tuple[int, int]:
    """(width, height): multiples of 4, about square, holding `count` pixels."""
    width = 4 * math.ceil(math.sqrt(count) / 4)
    return width, 4 * math.ceil(count / width / 4)


def _webp(rgba: np.ndarray, size: tuple[int, int]) -> bytes:
    """A lossless WebP of `rgba` (count, 4) uint8, padded with zeros to `size`."""
    width, height = size
    pixels = np.zeros((width * height, 4), np.uint8)
    pixels[: len(rgba)] = rgba
    out = io.BytesIO()
    Image.fromarray(pixels.reshape(height, width, 4), "RGBA").save(out, "WEBP", lossless=True, exact=True)
    return out.getvalue()


def _nearest(book: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Index of the nearest entry of the sorted `book` for each value."""
    upper = np.clip(np.searchsorted(book, values), 1, len(book) - 1)
    nearer_lower = np.abs(values - book[upper - 1]) <= np.abs(book[upper] - values)
    return np.where(nearer_lower, upper - 1, upper)


def _codebook(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(256 float32 entries, sorted; uint8 index of the nearest entry for each value)."""
    flat = values.astype(np.float64).ravel()
    book = np.quantile(flat, np.linspace(0.0, 1.0, CODEBOOK_SIZE))
    for _ in range(CODEBOOK_ITERATIONS):
        index = _nearest(book, flat)
        sums = np.bincount(index, weights=flat, minlength=CODEBOOK_SIZE)
        counts = np.bincount(index, minlength=CODEBOOK_SIZE)
        book = np.sort(np.where(counts > 0, sums / np.maximum(counts, 1), book))  # an empty entry stays
    book = book.astype(np.float32)
    return book, _nearest(book, values.astype(np.float32)).astype(np.uint8)


def _means(means: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[float], list[float]]:
    """(lower-byte RGB, upper-byte RGB, mins, maxs) of the log-transformed positions."""
    n = np.sign(means) * np.log1p(np.abs(means.astype(np.float64)))
    lo, hi = n.min(axis=0), n.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    q = np.round((n - lo) / span * 65535.0).astype(np.uint16)
    return (q & 0xFF).astype(np.uint8), (q >> 8).astype(np.uint8), lo.tolist(), hi.tolist()


def _quats(quats: np.ndarray) -> np.ndarray:
    """(count, 4) uint8 smallest-three rotations (w, x, y, z order; alpha = 252 + dropped index)."""
    q = quats.astype(np.float64) / np.linalg.norm(quats, axis=1, keepdims=True)
    largest = np.abs(q).argmax(axis=1)
    q = q * np.where(q[np.arange(len(q)), largest] < 0, -1.0, 1.0)[:, None]
    rgba = np.empty((len(q), 4), np.uint8)
    for i in range(4):
        rows = largest == i
        others = q[np.ix_(rows, [j for j in range(4) if j != i])]
        rgba[rows, :3] = np.clip(np.round((others / math.sqrt(2.0) + 0.5) * 255.0), 0, 255)
    rgba[:, 3] = 252 + largest
    return rgba


def write_sog(path: str | Path, gaussians: Gaussians) -> None:
    """Write `gaussians` as a `.sog` zip (module docstring; degree-0 colour only)."""
    g, count = gaussians, len(gaussians)
    size = _image_size(count)
    opaque = np.full((count, 1), 255, np.uint8)
    low, up, mins, maxs = _means(g.means)
    scale_book, scale_index = _codebook(g.log_scales)
    dc_book, dc_index = _codebook(g.sh[:, 0, :])
    alpha = np.round(np.clip(g.opacities, 0.0, 1.0) * 255.0).astype(np.uint8)[:, None]
    images = {
        "means_l.webp": np.hstack([low, opaque]),
        "means_u.webp": np.hstack([up, opaque]),
        "scales.webp": np.hstack([scale_index, opaque]),
        "quats.webp": _quats(g.quats),
        "sh0.webp": np.hstack([dc_index, alpha]),
    }
    meta = {
        "version": SOG_VERSION,
        "asset": {"generator": "bayesian-fields"},
        "count": count,
        "means": {"mins": mins, "maxs": maxs, "files": ["means_l.webp", "means_u.webp"]},
        "scales": {"codebook": scale_book.astype(float).tolist(), "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": dc_book.astype(float).tolist(), "files": ["sh0.webp"]},
    }
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as bundle:  # WebP is compressed already
        for name, rgba in images.items():
            bundle.writestr(name, _webp(rgba, size))
        bundle.writestr("meta.json", json.dumps(meta))
