"""Deterministic, field-by-field mutants of the `splat-transform` fixtures (issue 30, item 2).

Why a generator and not stored files: every field of every format is replaced in turn by values
of the wrong type or out of range, which is thousands of files; building them from the fixtures
at test time keeps the corpus in step with the readers and the fixtures. Each mutant is a set of
files (one, or a SOG folder) and the name of the one a reader opens; its `name` says what was
changed, so a failure reads as "sh3.glb accessors[0].count=huge".

Shared with the fuzz targets (`tests/fuzz/reader_strategies.py`), which start from the same
fixture parts and mutate them at random.
"""

from __future__ import annotations

import base64
import copy
import gzip
import io
import json
import struct
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
FIXTURES = ROOT / "tests" / "fixtures" / "formats"
SPZ_MAGIC = 0x5053474E


@dataclass(frozen=True)
class Mutant:
    """Files to write into an empty folder, and the one the reader is given."""

    name: str
    files: dict[str, bytes]
    entry: str


MISSING = object()
"""Marks a key (or list item) deleted rather than replaced."""
WRONG_VALUES: tuple[tuple[str, Any], ...] = (
    ("string", "x"),
    ("numeric-string", "0"),
    ("float", 0.5),
    ("list", [1]),
    ("object", {"a": 1}),
    ("null", None),
    ("true", True),
    ("negative", -1),
    ("huge", 2**64),
    ("missing", MISSING),
)
"""What every JSON field is replaced by in turn: each wrong type, a bound on either side, absent."""


# -- JSON documents ------------------------------------------------------------------------


def json_paths(value: Any, path: tuple = (), *, items: int = 3) -> Iterator[tuple]:
    """Every node under `value` (not the root), depth first. Lists longer than `items` are
    walked at their first, middle and last items (a codebook's 256 numbers are alike)."""
    if isinstance(value, dict):
        children: list = list(value.items())
    elif isinstance(value, list):
        picks = range(len(value)) if len(value) <= items else sorted({0, len(value) // 2, len(value) - 1})
        children = [(i, value[i]) for i in picks]
    else:
        return
    for key, child in children:
        yield (*path, key)
        yield from json_paths(child, (*path, key), items=items)


def set_at(doc: Any, path: tuple, value: Any) -> Any:
    """A deep copy of `doc` with the node at `path` replaced by `value` (deleted for MISSING)."""
    out = copy.deepcopy(doc)
    parent = out
    for key in path[:-1]:
        parent = parent[key]
    if value is MISSING:
        del parent[path[-1]]
    else:
        parent[path[-1]] = copy.deepcopy(value)
    return out


def path_label(path: tuple) -> str:
    return "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path).lstrip(".")


def field_mutants(doc: Any) -> Iterator[tuple[str, Any]]:
    """(label, document) for every field of `doc` replaced by each of `WRONG_VALUES`."""
    for path in json_paths(doc):
        for label, value in WRONG_VALUES:
            yield f"{path_label(path)}={label}", set_at(doc, path, value)


# -- glTF / GLB ----------------------------------------------------------------------------


@cache
def glb_parts(name: str) -> tuple[dict, bytes]:
    """(JSON document, binary chunk) of a fixture .glb."""
    data = (FIXTURES / name).read_bytes()
    (json_length,) = struct.unpack_from("<I", data, 12)
    (bin_length,) = struct.unpack_from("<I", data, 20 + json_length)
    doc = json.loads(data[20 : 20 + json_length])
    return doc, data[28 + json_length : 28 + json_length + bin_length]


def glb(doc: Any, binary: bytes) -> bytes:
    """A GLB container of `doc` (any JSON value) and `binary`, lengths consistent."""
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = (
        struct.pack("<II", len(text), 0x4E4F534A)
        + text
        + struct.pack("<II", len(binary), 0x004E4942)
        + binary
    )
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


def gltf_embedded(doc: dict, binary: bytes) -> dict:
    """`doc` as a .gltf whose buffer is a base64 data URI."""
    out = copy.deepcopy(doc)
    out["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(binary).decode()
    return out


def _attributes(doc: dict) -> dict:
    return doc["meshes"][0]["primitives"][0]["attributes"]


ODD_URIS = (
    "",
    "data:",
    "data:,",
    "data:application/octet-stream;base64",
    "data:application/octet-stream;base64,!!!!",
    "data:application/octet-stream;base64,QUJD",
    "data:text/plain,abc",
    "/etc/passwd",
    "../../../../etc/passwd",
    "%2e%2e/%2e%2e/etc/passwd",
    "file:///etc/passwd",
    "http://169.254.169.254/latest",
    "missing.bin",
    "a\x00b.bin",
    ".",
    "sub/",
    "x" * 5000,
    "%ff%fe.bin",
)
"""Buffer URIs a hostile .gltf may carry: malformed data URIs, escapes, schemes, odd names."""


def gltf_mutants(name: str) -> Iterator[Mutant]:
    """Every JSON field of the fixture's document replaced (as .glb), the accessors' counts and
    offsets out of range, odd buffer URIs (as .gltf), and the GLB container's lengths broken."""
    doc, binary = glb_parts(name)
    stem = name.removesuffix(".glb")
    for label, changed in field_mutants(doc):
        yield Mutant(f"{name} {label}", {"splat.glb": glb(changed, binary)}, "splat.glb")
    position = _attributes(doc)["POSITION"]
    n = doc["accessors"][position]["count"]
    ranges: list[tuple[str, Callable[[dict], None]]] = []
    for i in (position, len(doc["accessors"]) - 1):
        for count in (0, 1, n - 1, n + 1, 2**31, 20_000_000):
            ranges.append(
                (f"accessors[{i}].count={count}", lambda d, i=i, c=count: d["accessors"][i].update(count=c))
            )
        for off in (4, 1 << 20, 2**40):
            ranges.append(
                (
                    f"accessors[{i}].byteOffset={off}",
                    lambda d, i=i, o=off: d["accessors"][i].update(byteOffset=o),
                )
            )
        for ctype in (5120, 5123, 5125, 5130, 0):
            ranges.append(
                (
                    f"accessors[{i}].componentType={ctype}",
                    lambda d, i=i, t=ctype: d["accessors"][i].update(componentType=t),
                )
            )
        for kind in ("VEC2", "MAT4", "SCALAR", "vec3"):
            ranges.append(
                (f"accessors[{i}].type={kind}", lambda d, i=i, k=kind: d["accessors"][i].update(type=k))
            )
        ranges.append(
            (f"accessors[{i}].normalized", lambda d, i=i: d["accessors"][i].update(normalized=True))
        )
    for v in (0, len(doc["bufferViews"]) - 1):
        for length in (0, 4, 2**40):
            ranges.append(
                (
                    f"bufferViews[{v}].byteLength={length}",
                    lambda d, v=v, x=length: d["bufferViews"][v].update(byteLength=x),
                )
            )
        for off in (4, len(binary), 2**40):
            ranges.append(
                (
                    f"bufferViews[{v}].byteOffset={off}",
                    lambda d, v=v, x=off: d["bufferViews"][v].update(byteOffset=x),
                )
            )
        for stride in (4, 12, 252, 256):
            ranges.append(
                (
                    f"bufferViews[{v}].byteStride={stride}",
                    lambda d, v=v, x=stride: d["bufferViews"][v].update(byteStride=x),
                )
            )
        ranges.append((f"bufferViews[{v}].buffer=1", lambda d, v=v: d["bufferViews"][v].update(buffer=1)))
    ranges += [
        ("buffers[0].byteLength=0", lambda d: d["buffers"][0].update(byteLength=0)),
        ("two buffers", lambda d: d["buffers"].append({"byteLength": 4})),
        ("no accessors", lambda d: d.update(accessors=[])),
        ("POSITION=last+1", lambda d: _attributes(d).update(POSITION=len(d["accessors"]))),
        ("attributes swapped", lambda d: _attributes(d).update(
            POSITION=_attributes(d)["KHR_gaussian_splatting:ROTATION"],
            **{"KHR_gaussian_splatting:ROTATION": _attributes(d)["POSITION"]})),
        ("extension removed", lambda d: d["meshes"][0]["primitives"][0].pop("extensions", None)),
        ("extension not an object", lambda d: d["meshes"][0]["primitives"][0].update(extensions=[1])),
        ("empty primitive", lambda d: d["meshes"][0]["primitives"].insert(0, {"attributes": {}})),
        ("SH band partly missing", lambda d: _attributes(d).pop("KHR_gaussian_splatting:SH_DEGREE_1_COEF_1", None)),
    ]  # fmt: skip
    for label, edit in ranges:
        changed = copy.deepcopy(doc)
        edit(changed)
        yield Mutant(f"{name} {label}", {"splat.glb": glb(changed, binary)}, "splat.glb")
    for uri in ODD_URIS:
        changed = copy.deepcopy(doc)
        changed["buffers"][0]["uri"] = uri
        yield Mutant(
            f"{stem}.gltf uri={uri[:40]!r}", {"splat.gltf": json.dumps(changed).encode()}, "splat.gltf"
        )
    beside = copy.deepcopy(doc)
    beside["buffers"][0]["uri"] = "splat.bin"
    yield Mutant(
        f"{stem}.gltf uri=file beside",
        {"splat.gltf": json.dumps(beside).encode(), "splat.bin": binary},
        "splat.gltf",
    )
    yield Mutant(
        f"{stem}.gltf uri=short file beside",
        {"splat.gltf": json.dumps(beside).encode(), "splat.bin": binary[:100]},
        "splat.gltf",
    )
    embedded = json.dumps(gltf_embedded(doc, binary)).encode()
    yield Mutant(f"{stem}.gltf embedded", {"splat.gltf": embedded}, "splat.gltf")
    for text in (b"", b"{", b"[]", b"null", b"1", b'"x"', b"\xff\xfe", b"[" * 100_000, b"{}"):
        yield Mutant(f"{stem}.gltf document={text[:8]!r}", {"splat.gltf": text}, "splat.gltf")
    for label, value in WRONG_VALUES[:-1]:
        yield Mutant(f"{name} document={label}", {"splat.glb": glb(value, binary)}, "splat.glb")
    yield from _glb_container_mutants(name, (FIXTURES / name).read_bytes())


def _glb_container_mutants(name: str, data: bytes) -> Iterator[Mutant]:
    (json_length,) = struct.unpack_from("<I", data, 12)
    bin_at = 20 + json_length

    def patched(offset: int, fmt: str, value: int) -> bytes:
        out = bytearray(data)
        struct.pack_into(fmt, out, offset, value)
        return bytes(out)

    edits = [
        ("magic", patched(0, "<I", 0x46546C68)),
        ("version=1", patched(4, "<I", 1)),
        ("version=huge", patched(4, "<I", 2**32 - 1)),
        ("total length=0", patched(8, "<I", 0)),
        ("total length=huge", patched(8, "<I", 2**32 - 1)),
        ("JSON length=0", patched(12, "<I", 0)),
        ("JSON length=odd", patched(12, "<I", json_length - 3)),
        ("JSON length=huge", patched(12, "<I", 2**32 - 1)),
        ("JSON type=BIN", patched(16, "<I", 0x004E4942)),
        ("BIN length=0", patched(bin_at, "<I", 0)),
        ("BIN length=+1", patched(bin_at, "<I", len(data) - bin_at - 8 + 1)),
        ("BIN length=huge", patched(bin_at, "<I", 2**32 - 1)),
        ("BIN type=JSON", patched(bin_at + 4, "<I", 0x4E4F534A)),
        ("JSON bytes not UTF-8", data[:20] + b"\xff" * json_length + data[bin_at:]),
        ("extended", data + bytes(1000)),
    ]
    for cut in (0, 12, 19, 20, bin_at - 1, bin_at + 4, bin_at + 8, len(data) // 2, len(data) - 1):
        edits.append((f"truncated at {cut}", data[:cut]))
    for label, blob in edits:
        yield Mutant(f"{name} container {label}", {"splat.glb": blob}, "splat.glb")


# -- SOG -----------------------------------------------------------------------------------


@cache
def sog_members(name: str = "tabletop.sog") -> dict[str, bytes]:
    with zipfile.ZipFile(FIXTURES / name) as archive:
        return {info.filename: archive.read(info) for info in archive.infolist()}


def sog_zip(members: dict[str, bytes], *, compression: int = zipfile.ZIP_STORED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression) as archive:
        for member, data in members.items():
            archive.writestr(member, data)
    return buf.getvalue()


def vp8l_with_size(data: bytes, width: int, height: int) -> bytes:
    """A lossless WebP whose header claims `width` x `height` (the bitstream unchanged)."""
    assert data[12:16] == b"VP8L" and data[20] == 0x2F
    (bits,) = struct.unpack_from("<I", data, 21)
    bits = (bits & ~((1 << 28) - 1)) | ((width - 1) & 0x3FFF) | (((height - 1) & 0x3FFF) << 14)
    out = bytearray(data)
    struct.pack_into("<I", out, 21, bits)
    return bytes(out)


def _png(width: int, height: int) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGBA", (width, height), (1, 2, 3, 252)).save(buf, format="PNG")
    return buf.getvalue()


def sog_mutants(name: str = "tabletop.sog") -> Iterator[Mutant]:
    """Every meta.json field replaced (zip), every member missing / emptied / truncated /
    swapped / lying about its size, the zip's own records broken, and a few folder bundles."""
    members = sog_members(name)
    meta = json.loads(members["meta.json"])

    def bundle(label: str, changed: dict[str, bytes]) -> Mutant:
        return Mutant(f"{name} {label}", {"splat.sog": sog_zip(changed)}, "splat.sog")

    for label, changed_meta in field_mutants(meta):
        yield bundle(f"meta.{label}", {**members, "meta.json": json.dumps(changed_meta).encode()})
    for count in (0, 1, meta["count"] - 1, meta["count"] + 1, 148 * 148, 148 * 148 + 1, 20_000_000, 2**31):
        yield bundle(
            f"meta.count={count}", {**members, "meta.json": json.dumps({**meta, "count": count}).encode()}
        )
    for label, value in WRONG_VALUES[:-1]:
        yield bundle(f"meta.json={label}", {**members, "meta.json": json.dumps(value).encode()})
    for text in (b"", b"{", b"\xff\xfe", b"[" * 100_000, b'{"version": 2, "count": 1e999}'):
        yield bundle(f"meta.json bytes {text[:8]!r}", {**members, "meta.json": text})
    images = [m for m in members if m.endswith(".webp")]
    for member in members:
        yield bundle(f"{member} missing", {k: v for k, v in members.items() if k != member})
        yield bundle(f"{member} empty", {**members, member: b""})
        yield bundle(f"{member} truncated", {**members, member: members[member][: len(members[member]) // 2]})
        yield bundle(f"{member} garbage", {**members, member: bytes(range(256)) * 8})
    for a, b in zip(images, images[1:] + images[:1], strict=True):
        yield bundle(f"{a} swapped with {b}", {**members, a: members[b], b: members[a]})
    first = images[0]
    for width, height in ((16383, 16383), (1, 1), (148, 147), (147, 148), (16383, 2), (296, 74)):
        yield bundle(
            f"{first} header says {width}x{height}",
            {**members, first: vp8l_with_size(members[first], width, height)},
        )
    yield bundle(f"{first} a PNG of the right size", {**members, first: _png(148, 148)})
    yield bundle(f"{first} a PNG too small", {**members, first: _png(10, 10)})
    yield bundle("extra member", {**members, "extra.bin": bytes(100)})
    yield bundle("member in a folder", {**members, "../evil.webp": members[first]})
    yield Mutant(
        f"{name} deflated", {"splat.sog": sog_zip(members, compression=zipfile.ZIP_DEFLATED)}, "splat.sog"
    )
    yield from _zip_record_mutants(name, (FIXTURES / name).read_bytes())
    yield Mutant(f"{name} as folder", {**members}, "meta.json")
    yield Mutant(
        f"{name} folder missing {first}", {k: v for k, v in members.items() if k != first}, "meta.json"
    )
    escape = {**meta, "means": {**meta["means"], "files": ["../means_l.webp", "means_u.webp"]}}
    yield Mutant(
        f"{name} folder file escapes", {**members, "meta.json": json.dumps(escape).encode()}, "meta.json"
    )


def _zip_record_mutants(name: str, data: bytes) -> Iterator[Mutant]:
    end = data.rfind(b"PK\x05\x06")
    central = data.find(b"PK\x01\x02")

    def patched(offset: int, fmt: str, value: int) -> bytes:
        out = bytearray(data)
        struct.pack_into(fmt, out, offset, value)
        return bytes(out)

    edits = [
        ("end record entries=0", patched(end + 10, "<H", 0)),
        ("end record entries=65535", patched(end + 10, "<H", 65535)),
        ("end record directory size=huge", patched(end + 12, "<I", 2**32 - 1)),
        ("end record directory offset=huge", patched(end + 16, "<I", 2**32 - 1)),
        ("first member size=huge", patched(central + 24, "<I", 2**32 - 2)),
        ("first member compressed size=0", patched(central + 20, "<I", 0)),
        ("first member method=99", patched(central + 10, "<H", 99)),
        ("first member crc wrong", patched(central + 16, "<I", 0)),
        ("first local header offset=huge", patched(central + 42, "<I", 2**31)),
        ("not a zip", b"PK" + bytes(100)),
        ("extended", data + bytes(1000)),
    ]
    for cut in (0, 4, len(data) // 2, end, len(data) - 1):
        edits.append((f"truncated at {cut}", data[:cut]))
    for label, blob in edits:
        yield Mutant(f"{name} zip {label}", {"splat.sog": blob}, "splat.sog")


# -- SPZ -----------------------------------------------------------------------------------


@cache
def spz_payload(name: str) -> bytes:
    """The fixture's uncompressed bytes for gzip SPZ (v1-3) or the file itself (v4)."""
    data = (FIXTURES / name).read_bytes()
    return gzip.decompress(data) if data[:2] == b"\x1f\x8b" else data


def _header_values(count: int) -> dict[str, tuple[str, int, tuple[int, ...]]]:
    """Header field -> (struct format, offset, values to try)."""
    return {
        "magic": ("<I", 0, (0, SPZ_MAGIC ^ 1, 2**32 - 1)),
        "version": ("<I", 4, (0, 1, 2, 3, 4, 5, 255, 2**32 - 1)),
        "count": ("<I", 8, (0, 1, count - 1, count + 1, 2 * count, 20_000_000, 2**31, 2**32 - 1)),
        "sh degree": ("<B", 12, (0, 1, 2, 3, 4, 255)),
        "fractional bits": ("<B", 13, (0, 1, 12, 23, 24, 255)),
        "flags": ("<B", 14, (1, 2, 255)),
    }


def spz_gzip_mutants(name: str) -> Iterator[Mutant]:
    """Header fields of a gzip SPZ at boundary / hostile values, and payloads cut or extended,
    inside a valid gzip stream, and the gzip stream itself broken."""
    raw = spz_payload(name)
    (count,) = struct.unpack_from("<I", raw, 8)
    for field, (fmt, offset, values) in _header_values(count).items():
        for value in values:
            out = bytearray(raw)
            struct.pack_into(fmt, out, offset, value)
            yield Mutant(f"{name} {field}={value}", {"splat.spz": gzip.compress(bytes(out), 1)}, "splat.spz")
    yield Mutant(
        f"{name} reserved=255", {"splat.spz": gzip.compress(raw[:15] + b"\xff" + raw[16:], 1)}, "splat.spz"
    )
    for cut in (0, 8, 15, 16, 17, len(raw) // 2, len(raw) - 1):
        yield Mutant(f"{name} payload cut at {cut}", {"splat.spz": gzip.compress(raw[:cut], 1)}, "splat.spz")
    yield Mutant(f"{name} payload extended", {"splat.spz": gzip.compress(raw + bytes(4096), 1)}, "splat.spz")
    data = (FIXTURES / name).read_bytes()
    for cut in (2, 10, 30, len(data) // 2, len(data) - 4, len(data) - 1):
        yield Mutant(f"{name} gzip cut at {cut}", {"splat.spz": data[:cut]}, "splat.spz")
    yield Mutant(f"{name} gzip crc wrong", {"splat.spz": data[:-8] + bytes(4) + data[-4:]}, "splat.spz")
    yield Mutant(
        f"{name} gzip body garbage", {"splat.spz": data[:10] + b"\xff" * (len(data) - 10)}, "splat.spz"
    )
    yield Mutant(f"{name} two gzip members", {"splat.spz": data + data}, "splat.spz")
    yield Mutant(f"{name} gzip then garbage", {"splat.spz": data + b"garbage!"}, "splat.spz")


def spz_v4_mutants(name: str) -> Iterator[Mutant]:
    """Header fields of an SPZ v4 (zstd streams) and its table of contents at hostile values,
    the streams cut, swapped or corrupted."""
    data = spz_payload(name)
    (count,) = struct.unpack_from("<I", data, 8)
    streams, toc = struct.unpack_from("<BI", data, 15)
    fields = _header_values(count)
    fields["stream count"] = ("<B", 15, (0, streams - 1, streams + 1, 255))
    fields["toc offset"] = ("<I", 16, (0, 31, 33, len(data) - 1, 2**32 - 1))
    for i in range(streams):
        fields[f"toc[{i}] compressed"] = ("<Q", toc + 16 * i, (0, 1, 2**40, 2**64 - 1))
        fields[f"toc[{i}] uncompressed"] = ("<Q", toc + 16 * i + 8, (0, 1, 2**40, 2**64 - 1))
    for field, (fmt, offset, values) in fields.items():
        for value in values:
            out = bytearray(data)
            struct.pack_into(fmt, out, offset, value)
            yield Mutant(f"{name} {field}={value}", {"splat.spz": bytes(out)}, "splat.spz")
    first = toc + 16 * streams
    for cut in (0, 4, 16, 31, 32, toc + 8, first, first + 10, len(data) // 2, len(data) - 1):
        yield Mutant(f"{name} cut at {cut}", {"splat.spz": data[:cut]}, "splat.spz")
    yield Mutant(f"{name} extended", {"splat.spz": data + bytes(4096)}, "splat.spz")
    yield Mutant(
        f"{name} first stream garbage",
        {"splat.spz": data[:first] + b"\xff" * 64 + data[first + 64 :]},
        "splat.spz",
    )
    yield Mutant(f"{name} gzip-wrapped v4", {"splat.spz": gzip.compress(data, 1)}, "splat.spz")


# -- compressed PLY ------------------------------------------------------------------------


def split_ply(data: bytes) -> tuple[list[str], bytes]:
    """(header lines without end_header, body) of a binary PLY."""
    at = data.index(b"end_header\n")
    return data[:at].decode().splitlines(), data[at + len(b"end_header\n") :]


def join_ply(lines: list[str], body: bytes) -> bytes:
    return ("\n".join([*lines, "end_header"]) + "\n").encode() + body


def ply_header_mutants(name: str, data: bytes, target: str) -> Iterator[Mutant]:
    """Every header line of a binary PLY replaced, removed or duplicated; element counts at
    boundaries; property types changed; the body cut or extended."""
    lines, body = split_ply(data)
    kind_counts: dict[str, int] = {}
    for i, line in enumerate(lines):
        words = line.split()
        if words[0] == "element":
            kind_counts[words[1]] = int(words[2])
            for value in (
                "0",
                "1",
                str(int(words[2]) - 1),
                str(int(words[2]) + 1),
                "20000000",
                "4294967297",
                "-1",
                "x",
            ):
                changed = [*lines[:i], f"element {words[1]} {value}", *lines[i + 1 :]]
                yield Mutant(f"{name} element {words[1]}={value}", {target: join_ply(changed, body)}, target)
        if words[0] in ("element", "property", "format") and (i < 30 or i == len(lines) - 1):
            yield Mutant(
                f"{name} line {i} removed", {target: join_ply(lines[:i] + lines[i + 1 :], body)}, target
            )
            yield Mutant(
                f"{name} line {i} doubled", {target: join_ply(lines[: i + 1] + lines[i:], body)}, target
            )
        if words[0] == "property" and (i < 30 or i == len(lines) - 1):
            for kind in ("uchar", "double", "int", "list uchar float"):
                if kind != words[1]:
                    changed = [*lines[:i], f"property {kind} {words[-1]}", *lines[i + 1 :]]
                    yield Mutant(f"{name} {words[-1]} as {kind}", {target: join_ply(changed, body)}, target)
            renamed = [*lines[:i], f"property {words[1]} {words[-1]}_x", *lines[i + 1 :]]
            yield Mutant(f"{name} {words[-1]} renamed", {target: join_ply(renamed, body)}, target)
    for fmt in ("ascii 1.0", "binary_big_endian 1.0", "binary_little_endian 2.0", "x"):
        changed = [f"format {fmt}" if line.startswith("format") else line for line in lines]
        yield Mutant(f"{name} format {fmt}", {target: join_ply(changed, body)}, target)
    for cut in (0, 1, len(body) // 2, len(body) - 1):
        yield Mutant(f"{name} body cut to {cut}", {target: join_ply(lines, body[:cut])}, target)
    yield Mutant(f"{name} body extended", {target: join_ply(lines, body + bytes(4096))}, target)
    yield Mutant(f"{name} no end_header", {target: data[: data.index(b"end_header")]}, target)
    yield Mutant(f"{name} header garbage", {target: b"ply\n" + bytes(range(256)) * 4}, target)


def compressed_ply_mutants(name: str) -> Iterator[Mutant]:
    """Header mutants, plus chunk bounds made non-finite or inverted."""
    data = (FIXTURES / name).read_bytes()
    yield from ply_header_mutants(name, data, "splat.compressed.ply")
    lines, body = split_ply(data)
    for value, label in (
        (np.float32(np.nan), "NaN"),
        (np.float32(np.inf), "inf"),
        (np.float32(-1e30), "-1e30"),
    ):
        changed = bytearray(body)
        struct.pack_into("<f", changed, 3 * 4, value)  # chunk 0's max_x
        yield Mutant(
            f"{name} chunk max_x={label}",
            {"splat.compressed.ply": join_ply(lines, bytes(changed))},
            "splat.compressed.ply",
        )


# -- formats the tests write (RGB PLY, .splat) ---------------------------------------------


def small_gaussians(n: int = 300):  # noqa: ANN201 - a Gaussians; typed loosely to keep imports light
    from bayesian_fields_core.scene.types import Gaussians

    rng = np.random.default_rng(7)
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    return Gaussians(
        means=rng.uniform(-1, 1, (n, 3)).astype(np.float32),
        log_scales=rng.uniform(-4, -2, (n, 3)).astype(np.float32),
        quats=quats / np.linalg.norm(quats, axis=1, keepdims=True),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        sh=rng.uniform(-1, 1, (n, 1, 3)).astype(np.float32),
    )


def rgb_ply_mutants(tmp: Path) -> Iterator[Mutant]:
    from .format_writers import write_rgb_ply

    path = tmp / "source.ply"
    write_rgb_ply(path, small_gaussians())
    yield from ply_header_mutants("rgb.ply", path.read_bytes(), "splat.ply")


def antimatter_mutants(tmp: Path) -> Iterator[Mutant]:
    from bayesian_fields_core.scene.formats.antimatter import write_antimatter

    path = tmp / "source.splat"
    write_antimatter(path, small_gaussians())
    data = path.read_bytes()
    for cut in (0, 1, 31, 32, 33, len(data) // 2, len(data) - 1):
        yield Mutant(f".splat cut to {cut}", {"splat.splat": data[:cut]}, "splat.splat")
    yield Mutant(".splat extended by a row", {"splat.splat": data + bytes(32)}, "splat.splat")
    for offset, field in ((0, "position x"), (12, "scale x")):
        for value in (float("nan"), float("inf"), -1.0, 0.0, 1e30, 1e-45):
            blob = data[:offset] + struct.pack("<f", value) + data[offset + 4 :]
            yield Mutant(f".splat {field}={value}", {"splat.splat": blob}, "splat.splat")
    yield Mutant(
        ".splat NaN scale",
        {"splat.splat": data[:12] + struct.pack("<f", float("nan")) + data[16:]},
        "splat.splat",
    )
    yield Mutant(".splat zero scale", {"splat.splat": data[:12] + bytes(12) + data[24:]}, "splat.splat")
    yield Mutant(
        ".splat zero rotation", {"splat.splat": data[:28] + bytes([128] * 4) + data[32:]}, "splat.splat"
    )
    yield Mutant(".splat all 0xff", {"splat.splat": b"\xff" * len(data)}, "splat.splat")


def bomb_mutants(tmp: Path) -> Iterator[Mutant]:
    """`bench/splat_bombs`' files that declare far more than they carry, one per format, sized
    so the scan of the valid ones stays short (the API test `test_upload_bombs` uses the full
    sizes): the memory bound is what they test."""
    from bench import splat_bombs as bombs

    builders: dict[str, Callable[[Path], Path]] = {
        "spz gzip zeros 300k SH3": lambda d: bombs.spz_gzip_zeros(d, n=300_000),
        "spz zstd zeros 300k SH3": lambda d: bombs.spz_zstd_zeros(d, n=300_000),
        "sog constant 512x512": lambda d: bombs.sog_constant(d, side=512),
        "sog meta.json inflates to 40 MB": lambda d: bombs.sog_meta_inflates(d, megabytes=40),
        "sog image header 16383x16383": bombs.sog_huge_header,
        "glb declares 20M over 16 bytes": bombs.glb_count,
        "glb JSON chunk declares 4 GB": bombs.glb_json_length,
        "compressed PLY declares 20M with 1 KB": bombs.compressed_short,
    }
    for label, build in builders.items():
        folder = tmp / f"bomb-{len(label)}-{label.split()[0]}"
        folder.mkdir(exist_ok=True)
        path = build(folder)
        yield Mutant(f"bomb: {label}", {path.name: path.read_bytes()}, path.name)
        path.unlink()
