"""Hostile uploads over real HTTP against the real API + S3 server (issue 12, items 2 and 3).

Camera files that name host files: the API (which runs on this machine, so the host file is
really there for it to open) must refuse them with a 422 whose text does not depend on whether
the host file exists, and must store nothing. Before the fix an existing, well-formed host image
was accepted (201: validation, and later the worker, read it) and a missing one answered "do not
exist": an oracle. Then the classes of uploads that answered 500: empty splats, JSON past the
recursion limit, archive members the filesystem cannot hold, unknown zip compression.
"""

from __future__ import annotations

import io
import json
import zipfile
from collections.abc import Callable
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image

from tests.services.conftest import scene_form
from tests.services.support.scene_factory import image_zip, zip_bytes

pytestmark = pytest.mark.integration


def _scene_ids(client: httpx.Client) -> set[str]:
    resp = client.get("/v1/scenes", params={"limit": 500})
    assert resp.status_code == 200
    return {s["id"] for s in resp.json()["items"]}


def _with_cameras(folder: Path, edit: Callable[[dict], None]) -> list:
    doc = json.loads((folder / "transforms.json").read_text())
    edit(doc)
    form = [p for p in scene_form(folder) if p[0] != "cameras"]
    return form + [("cameras", ("transforms.json", json.dumps(doc).encode()))]


@pytest.fixture(scope="module")
def host_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A host image and depth map the API could open (right size for the scene), and misses."""
    folder = tmp_path_factory.mktemp("hostdir")
    Image.new("RGB", (64, 48), (1, 2, 3)).save(folder / "secret.png")
    np.save(folder / "secret.npy", np.ones((48, 64), np.float32))
    return {
        "image": folder / "secret.png",
        "image_missing": folder / "gone.png",
        "depth": folder / "secret.npy",
        "depth_missing": folder / "gone.npy",
    }


def _absolute(p: Path) -> str:
    return str(p)


def _climbing(p: Path) -> str:
    return "../" * 40 + str(p).lstrip("/")  # lands on the host file from any temp folder


@pytest.mark.parametrize("spell", [_absolute, _climbing], ids=["absolute", "dotdot"])
@pytest.mark.parametrize("key", ["file_path", "depth_file_path"])
def test_camera_paths_outside_the_upload_are_refused_alike(
    key: str, spell, client_a: httpx.Client, scene_dir: Path, stored_scene: dict, host_files: dict
) -> None:
    kind = "image" if key == "file_path" else "depth"
    before = _scene_ids(client_a)
    details = []
    for target in (host_files[kind], host_files[f"{kind}_missing"]):

        def edit(doc: dict, target: Path = target) -> None:
            doc["frames"][2][key] = spell(target)

        resp = client_a.post("/v1/scenes", files=_with_cameras(scene_dir, edit))
        assert resp.status_code == 422, resp.text
        details.append(resp.json()["detail"].replace(target.name, "NAME"))
    assert details[0] == details[1]  # no file-existence oracle
    assert "transforms.json frames[2]" in details[0]
    assert ("absolute" if spell is _absolute else "leaves the scene folder") in details[0]
    assert "/tmp/bfields" not in details[0] and "exist" not in details[0]
    assert _scene_ids(client_a) == before  # nothing stored, so no job can ever read the host file
    assert client_a.get(f"/v1/scenes/{stored_scene['id']}").json() == stored_scene


def _replace(form: list, field: str, name: str, data: bytes) -> list:
    return [p for p in form if p[0] != field] + [(field, (name, data))]


def _empty_ply() -> bytes:
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
    names += [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)]
    header = "ply\nformat binary_little_endian 1.0\nelement vertex 0\n"
    return (header + "".join(f"property float {n}\n" for n in names) + "end_header\n").encode()


def _zip_method_99(folder: Path) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as zf:
        zf.writestr("frame_000.png", (folder / "images" / "frame_000.png").read_bytes())
    blob = bytearray(buf.getvalue())
    blob[8:10] = (99).to_bytes(2, "little")
    central = blob.rfind(b"PK\x01\x02")
    blob[central + 10 : central + 12] = (99).to_bytes(2, "little")
    return bytes(blob)


HOSTILE: dict[str, tuple[Callable[[Path], list], list[str]]] = {
    "zero gaussians": (
        lambda d: _replace(scene_form(d), "splat", "splat.ply", _empty_ply()),
        ["no Gaussians"],
    ),
    "deep transforms.json": (
        lambda d: _replace(scene_form(d), "cameras", "transforms.json", b"[" * 100_000 + b"]" * 100_000),
        ["transforms.json", "nested too deeply"],
    ),
    "deep cameras.json": (
        lambda d: _replace(
            scene_form(d), "cameras", "cameras.json", b'{"a":' * 60_000 + b"1" + b"}" * 60_000
        ),
        ["cameras.json", "nested too deeply"],
    ),
    "file and folder of one name": (
        lambda d: _replace(
            scene_form(d), "images", "images.zip", zip_bytes({"a.png": b"1", "a.png/b.png": b"2"})
        ),
        ["images.zip", "both a file and a folder"],
    ),
    "component past NAME_MAX": (
        lambda d: _replace(scene_form(d), "images", "images.zip", zip_bytes({"n" * 300 + ".png": b"1"})),
        ["images.zip", "at most 255"],
    ),
    "very deep path": (
        lambda d: _replace(
            scene_form(d), "images", "images.zip", zip_bytes({"d/" * 2000 + "a.png": b"1", "b.png": b"2"})
        ),
        ["images.zip", "too deep"],
    ),
    "unsupported compression": (
        lambda d: _replace(scene_form(d), "images", "images.zip", _zip_method_99(d)),
        ["images.zip", "compression method 99"],
    ),
    "multibyte file name past NAME_MAX": (
        lambda d: _replace(scene_form(d), "images", "é" * 126 + ".png", b"x"),
        ["255 bytes"],
    ),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_upload_is_a_4xx_naming_the_problem(
    case: str, client_a: httpx.Client, scene_dir: Path, stored_scene: dict
) -> None:
    build, fragments = HOSTILE[case]
    before = _scene_ids(client_a)
    resp = client_a.post("/v1/scenes", files=build(scene_dir))
    assert resp.status_code == 422, (case, resp.status_code, resp.text)
    detail = resp.json()["detail"]
    for fragment in fragments:
        assert fragment in detail, (case, detail)
    assert "/tmp" not in detail
    assert _scene_ids(client_a) == before
    assert client_a.get(f"/v1/scenes/{stored_scene['id']}").json() == stored_scene


def test_good_upload_still_works(client_a: httpx.Client, scene_dir: Path) -> None:
    resp = client_a.post("/v1/scenes", files=scene_form(scene_dir, images_zip=image_zip(scene_dir)))
    assert resp.status_code == 201, resp.text
    assert resp.json()["summary"]["warnings"] == []


def test_presigned_upload_naming_a_host_file_never_becomes_a_job(
    client_a: httpx.Client, scene_dir: Path, host_files: dict
) -> None:
    """The presigned path runs the same checks at /complete: refused, the scene stays unready, so
    no job (and no worker) can ever be pointed at the host file."""
    doc = json.loads((scene_dir / "transforms.json").read_text())
    doc["frames"][0]["file_path"] = str(host_files["image"])
    files = {
        ("splat", "splat.ply"): (scene_dir / "splat.ply").read_bytes(),
        ("cameras", "transforms.json"): json.dumps(doc).encode(),
        ("images", "images.zip"): image_zip(scene_dir),
    }
    specs = [{"field": f, "name": n, "size": len(data)} for (f, n), data in files.items()]
    plan = client_a.post("/v1/scenes/uploads", json={"files": specs})
    assert plan.status_code == 201, plan.text
    for up in plan.json()["uploads"]:
        assert (
            httpx.put(up["part_urls"][0], content=files[(up["field"], up["name"])], timeout=30).status_code
            == 200
        )
    scene_id = plan.json()["scene_id"]
    done = client_a.post(f"/v1/scenes/{scene_id}/complete")
    assert done.status_code == 422 and "is absolute" in done.json()["detail"], done.text
    assert client_a.get(f"/v1/scenes/{scene_id}").json()["state"] == "uploading"
    assert client_a.post("/v1/jobs", json={"scene_id": scene_id, "tasks": ["get mug"]}).status_code == 409
