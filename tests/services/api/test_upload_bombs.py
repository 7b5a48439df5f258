"""Issue 30's hostile splats through the real API (uvicorn subprocess, S3 stand-in): files that
declare far more than they carry, glTF / SOG metadata of the wrong types, SPZ values outside the
specification. Each answer is a 201 or a 422 naming the file and the field, never a 500; the
API's peak resident size grows by less than `MAX_GROWTH_MIB` over all of them; the kept-alive
connection still serves a good upload afterwards; nothing stored before is touched."""

from __future__ import annotations

import copy
import gzip
import json
import zipfile
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from bench import splat_bombs
from tests.core.scene.splat_mutations import glb, glb_parts
from tests.integration.fixtures.services import ApiServer
from tests.services.conftest import scene_form

pytestmark = pytest.mark.integration

FIXTURES = Path(__file__).resolve().parents[3] / "tests" / "fixtures" / "formats"
MAX_GROWTH_MIB = 150
"""Issue 30's bound on the API's memory while it checks any upload."""
BOMB_GAUSSIANS = 1_000_000
"""Gaussians the SPZ bombs declare here (the bench uses the issue's 2 M; half keeps the test short)."""


def _vm_hwm_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM in /proc status")


def _with_splat(scene_dir: Path, splat: Path) -> list:
    form = scene_form(scene_dir)
    return [("splat", (splat.name, splat.read_bytes())), *form[1:]]


BOMBS: dict[str, tuple[Callable[[Path], Path], str | None]] = {
    "spz_gzip_zeros": (lambda d: splat_bombs.spz_gzip_zeros(d, n=BOMB_GAUSSIANS), None),
    "spz_zstd_zeros": (lambda d: splat_bombs.spz_zstd_zeros(d, n=BOMB_GAUSSIANS), None),
    "sog_constant": (splat_bombs.sog_constant, None),
    "sog_meta_inflates": (splat_bombs.sog_meta_inflates, "'meta.json' declares"),
    "sog_huge_header": (splat_bombs.sog_huge_header, "'means_l.webp' is too large"),
    "glb_count": (splat_bombs.glb_count, "needs 240000000 bytes"),
    "glb_json_length": (splat_bombs.glb_json_length, "JSON chunk"),
    "compressed_short": (splat_bombs.compressed_short, "truncated"),
}
"""Each bomb and what its 422 must say (None: a valid, if useless, splat; 201 or a 422 of the
alignment check, both fine: the point is the memory)."""


def test_bombs_stay_within_the_memory_bound(
    api: ApiServer, client_a: httpx.Client, scene_dir: Path, tmp_path: Path
) -> None:
    assert api.process is not None and api.process.pid is not None
    client_a.post("/v1/scenes", files=scene_form(scene_dir))  # the first upload's imports, not a bomb's
    before = _vm_hwm_mib(api.process.pid)
    answers = {}
    for name, (build, expected) in BOMBS.items():
        folder = tmp_path / name
        folder.mkdir()
        resp = client_a.post("/v1/scenes", files=_with_splat(scene_dir, build(folder)), timeout=120)
        answers[name] = (resp.status_code, resp.text[:300])
        assert resp.status_code in (201, 422), (name, resp.text)
        if expected is not None:
            assert resp.status_code == 422 and expected in resp.json()["detail"], (name, resp.text)
    growth = _vm_hwm_mib(api.process.pid) - before
    assert growth < MAX_GROWTH_MIB, (growth, answers)


def _position(doc: dict) -> dict:
    return doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]


GLTF_CASES: list[tuple[str, Callable[[dict], None], str, bool]] = [
    ("count as a string", lambda d: _position(d).update(count="21650"), "count: Input should be a valid integer", False),
    ("count as a float", lambda d: _position(d).update(count=21650.5), "count: Input should be a valid integer", False),
    ("count as a list", lambda d: _position(d).update(count=[1]), "count: Input should be a valid integer", False),
    ("POSITION as a string", lambda d: d["meshes"][0]["primitives"][0]["attributes"].update(POSITION="0"),
     "attributes.POSITION: Input should be a valid integer", False),
    ("POSITION out of range", lambda d: d["meshes"][0]["primitives"][0]["attributes"].update(POSITION=99999),
     "accessors[99999], which does not exist", False),
    ("meshes a string", lambda d: d.update(meshes="x"), "field meshes: Input should be a valid list", False),
    ("primitives of numbers", lambda d: d["meshes"][0].update(primitives=[1, 2]),
     "meshes[0].primitives[0]: Input should be a valid dictionary", False),
    ("uri a number", lambda d: d["buffers"][0].update(uri=5), "buffers[0].uri: Input should be a valid string", True),
    ("data: uri without a comma", lambda d: d["buffers"][0].update(uri="data:application/octet-stream;base64"),
     "data: URI without ';base64,'", True),
    ("uri /etc/passwd", lambda d: d["buffers"][0].update(uri="/etc/passwd"), "'/etc/passwd' is absolute", True),
]  # fmt: skip


def _spz_with_fraction(bits: int) -> bytes:
    with gzip.open(FIXTURES / "tabletop.v3.spz") as f:
        raw = bytearray(f.read())
    raw[13] = bits
    return gzip.compress(bytes(raw))


def _sog_with(edit: Callable[[dict], None]) -> bytes:
    out = zipfile.ZipFile(FIXTURES / "tabletop.sog")
    members = {info.filename: out.read(info) for info in out.infolist()}
    meta = json.loads(members["meta.json"])
    edit(meta)
    members["meta.json"] = json.dumps(meta).encode()
    import io

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return buf.getvalue()


def test_malformed_metadata_is_a_422_naming_the_field_on_one_kept_alive_connection(
    client_a: httpx.Client, scene_dir: Path, stored_scene: dict
) -> None:
    doc, binary = glb_parts("sh3.glb")
    uploads: list[tuple[str, str, bytes, str]] = []
    for label, edit, expected, as_gltf in GLTF_CASES:
        changed = copy.deepcopy(doc)
        edit(changed)
        if as_gltf:
            uploads.append((label, "splat.gltf", json.dumps(changed).encode(), expected))
        else:
            uploads.append((label, "splat.glb", glb(changed, binary), expected))
    for bits in (0, 24, 255):
        uploads.append(
            (f"SPZ fractional bits {bits}", "splat.spz", _spz_with_fraction(bits), f"fractional bits {bits}")
        )
    uploads.append(("SOG sh0 codebook an object", "splat.sog",
                    _sog_with(lambda m: m["sh0"].update(codebook={"a": 1})), "sh0.codebook: Input should be a valid list"))  # fmt: skip
    uploads.append(("SOG count a string", "splat.sog", _sog_with(lambda m: m.update(count="9")), "count: Input should be a valid integer"))  # fmt: skip
    form = scene_form(scene_dir)
    for label, name, data, expected in uploads:
        resp = client_a.post("/v1/scenes", files=[("splat", (name, data)), *form[1:]])
        assert resp.status_code == 422, (label, resp.text)
        detail = resp.json()["detail"]
        assert expected in detail and name in detail and "\n" not in detail, (label, detail)
    good = client_a.post("/v1/scenes", files=form)  # the same kept-alive connection still serves
    assert good.status_code == 201, good.text
    stored = client_a.get(f"/v1/scenes/{stored_scene['id']}")
    assert stored.status_code == 200 and stored.json()["state"] == "ready"
