"""Scene uploads over HTTP against the real API + S3 server: good uploads, every malformed kind
(4xx naming the problem, nothing stored, earlier data intact) and the size/bomb guards."""

from __future__ import annotations

import io
import json
import tarfile
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest
from PIL import Image

from tests.integration.fixtures.s3_server import S3Server
from tests.services.conftest import MAX_EXPANDED, MAX_UPLOAD, scene_form
from tests.services.support.scene_factory import image_zip, zip_bytes
from tests.support.scene_transforms import copy_scene, flip_camera_convention

pytestmark = pytest.mark.integration


def _scene_ids(client: httpx.Client) -> set[str]:
    resp = client.get("/v1/scenes", params={"limit": 500})
    assert resp.status_code == 200
    return {s["id"] for s in resp.json()["items"]}


def test_upload_with_image_zip(client_a: httpx.Client, scene_dir: Path) -> None:
    resp = client_a.post("/v1/scenes", files=scene_form(scene_dir, images_zip=image_zip(scene_dir)))
    assert resp.status_code == 201, resp.text
    scene = resp.json()
    assert scene["state"] == "ready"
    assert scene["summary"]["frames"] == 4 and scene["summary"]["gaussians"] == 2400
    assert scene["files"] == 6  # splat + transforms + 4 images
    got = client_a.get(f"/v1/scenes/{scene['id']}")
    assert got.status_code == 200 and got.json() == scene
    assert scene["id"] in _scene_ids(client_a)


def test_upload_with_image_files_and_delete(client_a: httpx.Client, scene_dir: Path) -> None:
    resp = client_a.post("/v1/scenes", files=scene_form(scene_dir), data={"name": "files"})
    assert resp.status_code == 201, resp.text
    scene = resp.json()
    assert scene["name"] == "files" and scene["summary"]["camera_format"] == "transforms"
    assert client_a.delete(f"/v1/scenes/{scene['id']}").status_code == 204
    assert client_a.get(f"/v1/scenes/{scene['id']}").status_code == 404
    assert scene["id"] not in _scene_ids(client_a)


def _replace(form: list, field: str, name: str, data: bytes) -> list:
    """The form with every part of `field` replaced by one file."""
    return [p for p in form if p[0] != field] + [(field, (name, data))]


def _resized_image(folder: Path) -> list:
    form = scene_form(folder)
    buf = io.BytesIO()
    Image.open(folder / "images" / "frame_001.png").resize((32, 24)).save(buf, format="PNG")
    return [p for p in form if p[1][0] != "frame_001.png"] + [("images", ("frame_001.png", buf.getvalue()))]


def _tar_gz_bomb() -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tf:
        info = tarfile.TarInfo("images/zeros.png")
        info.size = MAX_EXPANDED + 1
        tf.addfile(info, io.BytesIO(bytes(info.size)))
    return buf.getvalue()


BAD_UPLOADS: dict[str, tuple[Callable[[Path], list], int, list[str]]] = {
    "malformed ply": (
        lambda d: _replace(
            scene_form(d), "splat", "splat.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 10\n"
        ),
        422,
        ["splat.ply"],
    ),
    "not a ply": (
        lambda d: _replace(scene_form(d), "splat", "splat.txt", b"hello"),
        422,
        ["splat.txt", ".ply"],
    ),
    "camera json broken": (
        lambda d: _replace(scene_form(d), "cameras", "transforms.json", b"{not json"),
        422,
        ["transforms.json"],
    ),
    "unsupported camera file": (
        lambda d: _replace(scene_form(d), "cameras", "poses.csv", b"1,2,3"),
        422,
        ["poses.csv", "not a supported camera file"],
    ),
    "cameras disagree with images": (
        lambda d: _replace(
            scene_form(d),
            "cameras",
            "transforms.json",
            json.dumps(
                {
                    **json.loads((d / "transforms.json").read_text()),
                    "frames": [
                        {**f, "w": 100} for f in json.loads((d / "transforms.json").read_text())["frames"]
                    ],
                }  # fmt: skip
            ).encode(),
        ),
        422,
        ["frame_000.png"],
    ),
    "image size mismatch": (_resized_image, 422, ["frame_001.png", "32"]),
    "zip with ..": (
        lambda d: _replace(scene_form(d), "images", "images.zip", zip_bytes({"../evil.png": b"x"})),
        422,
        ["images.zip", "'..'"],
    ),
    "zip with absolute path": (
        lambda d: _replace(scene_form(d), "images", "images.zip", zip_bytes({"/etc/evil.png": b"x"})),
        422,
        ["images.zip", "absolute"],
    ),
    "zip with symlink": (
        lambda d: _replace(
            scene_form(d),
            "images",
            "images.zip",
            zip_bytes({"a.png": b"x"}, symlinks={"b.png": "/etc/passwd"}),
        ),
        422,
        ["images.zip", "symbolic link"],
    ),
    "too many members": (
        lambda d: _replace(
            scene_form(d), "images", "images.zip", zip_bytes({f"{i}.png": b"" for i in range(101)})
        ),
        422,
        ["101 members"],
    ),
    "zip bomb": (
        lambda d: _replace(
            scene_form(d), "images", "images.zip", zip_bytes({"zeros.png": bytes(MAX_EXPANDED + 1)})
        ),
        422,
        ["images.zip", "decompression bomb"],
    ),
    "tar.gz bomb": (
        lambda d: _replace(scene_form(d), "images", "images.tar.gz", _tar_gz_bomb()),
        422,
        ["images.tar.gz", "decompression bomb"],
    ),
    "too large": (
        lambda d: _replace(scene_form(d), "images", "big.png", bytes(MAX_UPLOAD + 1)),
        413,
        [f"limit of {MAX_UPLOAD} bytes"],
    ),
    "no images": (lambda d: [p for p in scene_form(d) if p[0] != "images"], 422, ["no images"]),
}


@pytest.mark.parametrize("case", sorted(BAD_UPLOADS))
def test_bad_upload_is_refused_and_stores_nothing(
    case: str, client_a: httpx.Client, scene_dir: Path, stored_scene: dict
) -> None:
    build, status, fragments = BAD_UPLOADS[case]
    before = _scene_ids(client_a)
    resp = client_a.post("/v1/scenes", files=build(scene_dir))
    assert resp.status_code == status, resp.text
    detail = resp.json()["detail"]
    for fragment in fragments:
        assert fragment in detail, (case, detail)
    assert "/tmp" not in detail  # server paths never leak
    assert _scene_ids(client_a) == before
    intact = client_a.get(f"/v1/scenes/{stored_scene['id']}")
    assert intact.status_code == 200 and intact.json() == stored_scene


def test_upload_needs_multipart(client_a: httpx.Client) -> None:
    resp = client_a.post("/v1/scenes", json={"splat": "x"})
    assert resp.status_code == 415


def _presigned_upload(client: httpx.Client, files: dict[tuple[str, str], bytes]) -> tuple[str, dict]:
    """Start a presigned upload, PUT every part straight to the S3 server; returns (scene id, parts)."""
    specs = [{"field": f, "name": n, "size": len(data)} for (f, n), data in files.items()]
    resp = client.post("/v1/scenes/uploads", json={"name": "presigned", "files": specs})
    assert resp.status_code == 201, resp.text
    plan = resp.json()
    parts: dict[str, list[dict]] = {}
    for up in plan["uploads"]:
        data = files[(up["field"], up["name"])]
        assert len(up["part_urls"]) == 1  # small files: one (last) part
        put = httpx.put(up["part_urls"][0], content=data, timeout=30)
        assert put.status_code == 200, put.text
        parts[up["name"]] = [{"PartNumber": 1, "ETag": put.headers["ETag"]}]
    return plan["scene_id"], parts


def test_presigned_upload_then_complete(
    client_a: httpx.Client, client_b: httpx.Client, scene_dir: Path
) -> None:
    files = {
        ("splat", "splat.ply"): (scene_dir / "splat.ply").read_bytes(),
        ("cameras", "transforms.json"): (scene_dir / "transforms.json").read_bytes(),
        ("images", "images.zip"): image_zip(scene_dir),
    }
    scene_id, parts = _presigned_upload(client_a, files)
    assert client_a.get(f"/v1/scenes/{scene_id}").json()["state"] == "uploading"
    assert client_a.post("/v1/jobs", json={"scene_id": scene_id, "tasks": ["x"]}).status_code == 409
    assert client_b.post(f"/v1/scenes/{scene_id}/complete", json={"parts": parts}).status_code == 404
    done = client_a.post(f"/v1/scenes/{scene_id}/complete", json={"parts": parts})
    assert done.status_code == 200, done.text
    scene = done.json()
    assert scene["state"] == "ready" and scene["summary"]["frames"] == 4 and scene["files"] == 6
    assert client_a.post(f"/v1/scenes/{scene_id}/complete").status_code == 409  # only once


def test_scene_records_are_rows_not_bucket_objects(
    client_a: httpx.Client, s3_server: S3Server, scene_dir: Path
) -> None:
    """Upload, presigned upload + complete, list and delete leave no record object, listing
    marker or tombstone in the bucket: a scene's record is its row (`scenes.store`), and a
    delete leaves nothing of the scene behind."""
    store = s3_server.store()
    root = "tenants/tenant-a/"

    def legacy() -> list[str]:
        return [
            k for k in store.list(root)
            if k.endswith("/scene.json") or k.startswith((root + "index/", root + "tombstones/"))
        ]  # fmt: skip

    single = client_a.post("/v1/scenes", files=scene_form(scene_dir))
    assert single.status_code == 201, single.text
    files = {
        ("splat", "splat.ply"): (scene_dir / "splat.ply").read_bytes(),
        ("cameras", "transforms.json"): (scene_dir / "transforms.json").read_bytes(),
        ("images", "images.zip"): image_zip(scene_dir),
    }
    presigned, parts = _presigned_upload(client_a, files)
    assert client_a.post(f"/v1/scenes/{presigned}/complete", json={"parts": parts}).status_code == 200
    ids = [single.json()["id"], presigned]
    assert set(ids) <= _scene_ids(client_a)
    assert legacy() == []
    for scene_id in ids:
        assert store.list(f"{root}scenes/{scene_id}/input/")
        assert client_a.delete(f"/v1/scenes/{scene_id}").status_code == 204
        assert store.list(f"{root}scenes/{scene_id}/") == []
        assert store.list_multipart_uploads(f"{root}scenes/{scene_id}/") == []
    assert not set(ids) & _scene_ids(client_a)
    assert legacy() == []


def test_presigned_upload_with_bad_file_stays_unready(client_a: httpx.Client, scene_dir: Path) -> None:
    files = {
        ("splat", "splat.ply"): b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n",
        ("cameras", "transforms.json"): (scene_dir / "transforms.json").read_bytes(),
        ("images", "images.zip"): image_zip(scene_dir),
    }
    scene_id, _ = _presigned_upload(client_a, files)
    resp = client_a.post(f"/v1/scenes/{scene_id}/complete")  # server lists the parts itself
    assert resp.status_code == 422 and "splat.ply" in resp.json()["detail"]
    assert client_a.get(f"/v1/scenes/{scene_id}").json()["state"] == "uploading"
    too_big = client_a.post(
        "/v1/scenes/uploads", json={"files": [{"field": "images", "name": "a.zip", "size": MAX_UPLOAD + 1}]}
    )
    assert too_big.status_code == 413 and str(MAX_UPLOAD) in too_big.json()["detail"]


def test_upload_of_a_splat_behind_its_cameras_gets_422_with_the_reason(
    client_a: httpx.Client, scene_dir: Path, tmp_path: Path
) -> None:
    """The geometric alignment check at upload: OpenCV poses written where OpenGL ones belong put
    the splat behind every camera; the form field alignment_check=false accepts it anyway."""
    flipped = flip_camera_convention(copy_scene(scene_dir, tmp_path / "flipped"))
    before = _scene_ids(client_a)
    resp = client_a.post("/v1/scenes", files=scene_form(flipped))
    assert resp.status_code == 422, resp.text
    detail = resp.json()["detail"]
    assert detail.startswith("alignment: ") and "\n" not in detail, detail
    assert "OpenGL" in detail and "alignment_check=false" in detail
    assert _scene_ids(client_a) == before
    forced = client_a.post("/v1/scenes", files=scene_form(flipped), data={"alignment_check": "false"})
    assert forced.status_code == 201, forced.text
    assert "alignment" not in forced.json()["summary"]
    good = client_a.post("/v1/scenes", files=scene_form(scene_dir))
    assert good.status_code == 201 and good.json()["summary"]["alignment"]["frustum_share"] > 0.9
    bad_flag = client_a.post("/v1/scenes", files=scene_form(scene_dir), data={"alignment_check": "maybe"})
    assert bad_flag.status_code == 422 and "alignment_check" in bad_flag.json()["detail"]
