"""Hostile splat files that declare far more than they carry: one per format, for the upload
memory benchmark (`bench_upload_memory.py --bombs`) and the API tests of issue 30.

Each builder writes a small file into a folder and returns its path. What they attack:

  spz_gzip_zeros     SPZ v3, 2 M Gaussians at SH degree 3, an all-zero payload (~126 KB of gzip)
  spz_zstd_zeros     SPZ v4, the same through zstd streams (a few KB)
  sog_constant       .sog of five constant lossless 2048 x 2048 WebPs declaring 4,194,304
  sog_meta_inflates  .sog whose meta.json inflates to 600 MB (0.6 MB zipped)
  sog_huge_header    .sog whose means_l.webp header says 16383 x 16383
  glb_count          .glb whose accessors declare 20 M Gaussians over a 16-byte buffer
  glb_json_length    .glb whose JSON chunk declares 4 GB
  compressed_short   compressed PLY declaring 20 M Gaussians with a 1 KB body

Built without holding what they declare (the zero streams are compressed chunk by chunk).
"""

from __future__ import annotations

import gzip
import io
import json
import struct
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

SPZ_MAGIC = 0x5053474E
ZEROS = bytes(1 << 20)


def _spz_sizes(n: int, degree: int) -> list[int]:
    """Bytes of each v3/v4 block for `n` Gaussians (positions, alphas, colours, scales, rotations, SH)."""
    sh = ((degree + 1) ** 2 - 1) * 3
    return [9 * n, n, 3 * n, 3 * n, 4 * n, sh * n]


def spz_gzip_zeros(folder: Path, n: int = 2_000_000, degree: int = 3) -> Path:
    path = folder / "bomb.spz"
    with gzip.GzipFile(path, "wb", compresslevel=9) as f:
        f.write(struct.pack("<IIIBBBB", SPZ_MAGIC, 3, n, degree, 12, 0, 0))
        left = sum(_spz_sizes(n, degree))
        while left:
            f.write(ZEROS[: min(left, len(ZEROS))])
            left -= min(left, len(ZEROS))
    return path


def spz_zstd_zeros(folder: Path, n: int = 2_000_000, degree: int = 3) -> Path:
    import zstandard

    sizes = [s for s in _spz_sizes(n, degree) if s]
    streams = []
    for size in sizes:
        out = io.BytesIO()
        with zstandard.ZstdCompressor(level=19).stream_writer(out, closefd=False, size=size) as w:
            left = size
            while left:
                w.write(ZEROS[: min(left, len(ZEROS))])
                left -= min(left, len(ZEROS))
        streams.append(out.getvalue())
    head = struct.pack("<IIIBBBB", SPZ_MAGIC, 4, n, degree, 12, 0, len(streams)) + struct.pack("<I", 32)
    head += bytes(32 - len(head))
    toc = b"".join(struct.pack("<QQ", len(c), u) for c, u in zip(streams, sizes, strict=True))
    path = folder / "bomb.spz"
    path.write_bytes(head + toc + b"".join(streams))
    return path


def _sog_meta(count: int) -> dict:
    book = [float(v) for v in np.linspace(-1.0, 1.0, 256)]
    return {
        "version": 2,
        "count": count,
        "means": {
            "mins": [-1.0, -1.0, -1.0],
            "maxs": [1.0, 1.0, 1.0],
            "files": ["means_l.webp", "means_u.webp"],
        },
        "scales": {"codebook": book, "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": book, "files": ["sh0.webp"]},
    }


def _webp(size: int, rgba: tuple[int, int, int, int]) -> bytes:
    from PIL import Image

    out = io.BytesIO()
    Image.new("RGBA", (size, size), rgba).save(out, format="WEBP", lossless=True)
    return out.getvalue()


def _zip(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return path


def sog_constant(folder: Path, side: int = 2048) -> Path:
    count = side * side
    image = _webp(side, (128, 128, 128, 255))
    quats = _webp(side, (128, 128, 128, 252))
    members = {"meta.json": json.dumps(_sog_meta(count)).encode()}
    for name in ("means_l.webp", "means_u.webp", "scales.webp", "sh0.webp"):
        members[name] = image
    members["quats.webp"] = quats
    return _zip(folder / "bomb.sog", members)


def sog_meta_inflates(folder: Path, megabytes: int = 600) -> Path:
    path = folder / "bomb.sog"
    with (
        zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf,
        zf.open("meta.json", "w", force_zip64=True) as m,
    ):
        m.write(b'{"version": 2, "pad": "')
        for _ in range(megabytes):
            m.write(b" " * (1 << 20))
        m.write(b'"}')
    return path


def _vp8l_with_size(webp: bytes, width: int, height: int) -> bytes:
    """A lossless WebP whose header is patched to say `width` x `height` (its pixels unchanged)."""
    at = webp.index(b"VP8L") + 8
    assert webp[at] == 0x2F, "not a simple lossless WebP"
    (bits,) = struct.unpack_from("<I", webp, at + 1)
    bits = (bits & ~((1 << 28) - 1)) | (width - 1) | ((height - 1) << 14)
    return webp[: at + 1] + struct.pack("<I", bits) + webp[at + 5 :]


def sog_huge_header(folder: Path) -> Path:
    count = 64 * 64
    image = _webp(64, (128, 128, 128, 255))
    members = {"meta.json": json.dumps(_sog_meta(count)).encode()}
    members["means_l.webp"] = _vp8l_with_size(image, 16383, 16383)
    for name in ("means_u.webp", "scales.webp", "sh0.webp"):
        members[name] = image
    members["quats.webp"] = _webp(64, (128, 128, 128, 252))
    return _zip(folder / "bomb.sog", members)


def _glb(doc: dict, binary: bytes, json_length: int | None = None) -> bytes:
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    binary += bytes(-len(binary) % 4)
    declared = len(text) if json_length is None else json_length
    body = (
        struct.pack("<II", declared, 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    )
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


def _gltf_doc(count: int) -> dict:
    names = {"POSITION": "VEC3", "KHR_gaussian_splatting:SCALE": "VEC3", "KHR_gaussian_splatting:ROTATION": "VEC4",
             "KHR_gaussian_splatting:OPACITY": "SCALAR", "COLOR_0": "VEC4"}  # fmt: skip
    accessors = [{"bufferView": 0, "componentType": 5126, "count": count, "type": t} for t in names.values()]
    return {
        "asset": {"version": "2.0"},
        "extensionsUsed": ["KHR_gaussian_splatting"],
        "buffers": [{"byteLength": 16}],
        "bufferViews": [{"buffer": 0, "byteLength": 16}],
        "accessors": accessors,
        "meshes": [
            {
                "primitives": [
                    {
                        "mode": 0,
                        "attributes": {k: i for i, k in enumerate(names)},
                        "extensions": {"KHR_gaussian_splatting": {}},
                    }
                ]
            }
        ],  # fmt: skip
    }


def glb_count(folder: Path, count: int = 20_000_000) -> Path:
    path = folder / "bomb.glb"
    path.write_bytes(_glb(_gltf_doc(count), bytes(16)))
    return path


def glb_json_length(folder: Path) -> Path:
    path = folder / "bomb.glb"
    path.write_bytes(_glb(_gltf_doc(1), bytes(16), json_length=0xFFFFFFFC))
    return path


def compressed_short(folder: Path, count: int = 20_000_000) -> Path:
    chunks = -(-count // 256)
    bounds = [f"{m}_{a}" for m in ("min", "max") for a in "xyz"] + [
        f"{m}_scale_{a}" for m in ("min", "max") for a in "xyz"
    ]
    header = "ply\nformat binary_little_endian 1.0\n"
    header += f"element chunk {chunks}\n" + "".join(f"property float {b}\n" for b in bounds)
    header += f"element vertex {count}\n" + "".join(
        f"property uint {p}\n" for p in ("packed_position", "packed_rotation", "packed_scale", "packed_color")
    )
    path = folder / "bomb.compressed.ply"
    path.write_bytes((header + "end_header\n").encode() + bytes(1024))
    return path


BOMBS: dict[str, Callable[[Path], Path]] = {
    "spz_gzip_zeros": spz_gzip_zeros,
    "spz_zstd_zeros": spz_zstd_zeros,
    "sog_constant": sog_constant,
    "sog_meta_inflates": sog_meta_inflates,
    "sog_huge_header": sog_huge_header,
    "glb_count": glb_count,
    "glb_json_length": glb_json_length,
    "compressed_short": compressed_short,
}
"""Every bomb by name (module docstring)."""
