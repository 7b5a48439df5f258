"""Fuzz every splat reader (issue 30, item 2): structure-aware cases built from the
splat-transform fixtures, one target per reader. The property is the corpus's
(`tests/core/scene/reader_check.check_splat_file`): the file loads (and loads whole), or the reader
raises an InputError naming the file, within the memory bound; never any other exception. Every
reader has a target: glTF / GLB, SOG, SPZ, compressed PLY, RGB PLY, antimatter `.splat` (the
INRIA PLY reader's is in `test_fuzz_library`), plus bytes flipped in every splat-transform fixture.

Why random on top of the deterministic corpus (`tests/core/scene/test_reader_corpus.py`): the corpus
changes one field at a time to a fixed list of values; these change several at once, to values
hypothesis draws and shrinks, and flip bytes the field-aware mutants never touch.
Budgets (full CI run, `BFIELDS_FUZZ_SCALE=1`) are the numbers passed to `budget`.
"""

from __future__ import annotations

import functools
import gzip
import tempfile
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.core.scene.reader_check import check_splat_file
from tests.core.scene.splat_mutations import (
    FIXTURES,
    MISSING,
    glb,
    glb_parts,
    join_ply,
    json_paths,
    set_at,
    small_gaussians,
    sog_members,
    sog_zip,
    split_ply,
    spz_payload,
)

from .conftest import budget, count

pytestmark = pytest.mark.fuzz

JSON_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**70), 2**70)
    | st.floats(allow_nan=True)
    | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=8,
)
"""Any JSON value (NaN and integers past 64 bits included), small."""
REPLACEMENTS = JSON_VALUES | st.just(MISSING)
SUFFIXES = (".glb", ".spz", ".sog", ".ply")
"""The fixture files a reader opens (the folder also holds a README and a SOG folder)."""


def _check(files: dict[str, bytes], entry: str) -> None:
    with tempfile.TemporaryDirectory(prefix="bf-fuzz-reader-") as tmp:
        folder = Path(tmp)
        for name, data in files.items():
            (folder / name).write_bytes(data)
        spill = folder / "spill"
        spill.mkdir()
        check_splat_file(folder / entry, spill, traced=False)


def _mutated_document(data: Any, doc: Any, edits: int) -> Any:
    paths = list(json_paths(doc))
    for _ in range(edits):
        path = data.draw(st.sampled_from(paths))
        try:
            doc = set_at(doc, path, data.draw(REPLACEMENTS))
        except (KeyError, IndexError, TypeError):  # an earlier edit removed or retyped a parent
            continue
    return doc


def _flipped(data: Any, raw: bytes, *, window: int | None = None) -> bytes:
    """`raw` with a few bytes replaced (within the first `window` bytes when given) and maybe cut."""
    out = bytearray(raw)
    limit = min(len(out), window or len(out))
    for _ in range(data.draw(st.integers(1, 6))):
        out[data.draw(st.integers(0, limit - 1))] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        out = out[: data.draw(st.integers(0, len(out)))]
    return bytes(out)


@budget(1500)
@given(data=st.data(), name=st.sampled_from(["tabletop.glb", "sh3.glb"]), edits=st.integers(1, 3))
def test_glb_documents(data: Any, name: str, edits: int) -> None:
    doc, binary = glb_parts(name)
    _check({"splat.glb": glb(_mutated_document(data, doc, edits), binary)}, "splat.glb")
    count("library: glTF / GLB document fields")


@budget(1500)
@given(data=st.data(), edits=st.integers(1, 3))
def test_sog_meta(data: Any, edits: int) -> None:
    import json

    members = dict(sog_members("tabletop.sog"))
    meta = _mutated_document(data, json.loads(members["meta.json"]), edits)
    members["meta.json"] = json.dumps(meta).encode()
    if data.draw(st.booleans()):  # and sometimes an image's bytes too
        image = data.draw(st.sampled_from(sorted(k for k in members if k.endswith(".webp"))))
        members[image] = _flipped(data, members[image], window=64)
    _check({"splat.sog": sog_zip(members)}, "splat.sog")
    count("library: SOG meta.json and members")


@budget(1500)
@given(data=st.data(), name=st.sampled_from(["tabletop.v3.spz", "tabletop.spz", "sh3.spz"]))
def test_spz(data: Any, name: str) -> None:
    raw = spz_payload(name)
    mutated = _flipped(data, raw, window=64 if data.draw(st.booleans()) else None)
    gzipped = (FIXTURES / name).read_bytes()[:2] == b"\x1f\x8b"
    _check({"splat.spz": gzip.compress(mutated, 1) if gzipped else mutated}, "splat.spz")
    count("library: SPZ header and payload")


def _ply_with_edits(data: Any, raw: bytes) -> bytes:
    """`raw` (a PLY) with up to three header words replaced and maybe bytes of its body flipped."""
    lines, body = split_ply(raw)
    for _ in range(data.draw(st.integers(0, 3))):
        at = data.draw(st.integers(1, len(lines) - 1))
        words = lines[at].split()
        words[data.draw(st.integers(0, len(words) - 1))] = data.draw(
            st.sampled_from(["0", "1", "-1", "4294967296", "float", "uchar", "list", "vertex", "chunk", "x"])
        )
        lines[at] = " ".join(words)
    if data.draw(st.booleans()):
        body = _flipped(data, body)
    return join_ply(lines, body)


@functools.cache
def _written(kind: str) -> bytes:
    """A small splat written by the project's own writer of that format (no fixture of it is
    made by splat-transform): the antimatter `.splat` rows, the RGB-instead-of-SH PLY."""
    from bayesian_fields_core.scene.formats.antimatter import write_antimatter
    from tests.core.scene.format_writers import write_rgb_ply

    with tempfile.TemporaryDirectory(prefix="bf-fuzz-src-") as tmp:
        path = Path(tmp) / f"source.{kind}"
        (write_antimatter if kind == "splat" else write_rgb_ply)(path, small_gaussians())
        return path.read_bytes()


@budget(1500)
@given(data=st.data(), name=st.sampled_from(["tabletop.compressed.ply", "sh3.compressed.ply"]))
def test_compressed_ply(data: Any, name: str) -> None:
    _check({"splat.ply": _ply_with_edits(data, (FIXTURES / name).read_bytes())}, "splat.ply")
    count("library: compressed PLY header and body")


@budget(800)
@given(data=st.data())
def test_rgb_ply(data: Any) -> None:
    _check({"splat.ply": _ply_with_edits(data, _written("ply"))}, "splat.ply")
    count("library: RGB PLY header and body")


@budget(800)
@given(data=st.data())
def test_antimatter_splat(data: Any) -> None:
    _check({"splat.splat": _flipped(data, _written("splat"))}, "splat.splat")
    count("library: .splat rows")


@budget(1500)
@given(
    data=st.data(), name=st.sampled_from(sorted(p.name for p in FIXTURES.glob("*.*") if p.suffix in SUFFIXES))
)
def test_any_fixture_bytes(data: Any, name: str) -> None:
    raw = (FIXTURES / name).read_bytes()
    suffix = "".join(Path(name).suffixes[-2:]) if name.endswith(".compressed.ply") else Path(name).suffix
    entry = "splat" + suffix.replace(".v3", "")
    _check({entry: _flipped(data, raw)}, entry)
    count("library: every reader, bytes flipped")
