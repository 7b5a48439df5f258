"""Every splat format and COLMAP 3.12's extra files through the real API (HTTP -> validator ->
S3), and `bfields submit`'s client on the folders `bfields run` reads: a gsplat result_dir with a
checkpoint (converted to a .ply on the user's machine) and a SOG folder (zipped to a .sog)."""

from __future__ import annotations

import io
import shutil
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest

from bayesian_fields_core.scene.colmap import write_colmap_text
from bayesian_fields_core.scene.layout import resolve_layout
from bayesian_fields_core.scene.ply import write_ply
from bayesian_fields_service.client import BFieldsClient
from tests.core.scene.test_trainer_runs import gsplat_run_folder
from tests.core.scene.trainer_layouts import SourceScene, small_source_scene
from tests.integration.fixtures.services import ApiServer

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "samples" / "tabletop"
FIXTURES = ROOT / "tests" / "fixtures" / "formats"


@pytest.fixture(scope="module")
def images_zip() -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for image in sorted((SAMPLE / "images").iterdir()):
            zf.write(image, image.name)
    return buf.getvalue()


def form(splat: Path, images_zip: bytes, cameras: list[Path] | None = None) -> list:
    cameras = cameras or [SAMPLE / "transforms.json"]
    return [
        ("splat", (splat.name, splat.read_bytes())),
        *(("cameras", (c.name, c.read_bytes())) for c in cameras),
        ("images", ("images.zip", images_zip)),
    ]


@pytest.mark.parametrize(
    ("name", "kind"),
    [
        ("tabletop.compressed.ply", "compressed_ply"),
        ("tabletop.spz", "spz"),
        ("tabletop.sog", "sog"),
    ],
)  # the 1.3 MB GLB with the images passes the test server's 2 MB upload limit; tests/core/scene reads it
def test_each_format_uploads(client_a: httpx.Client, images_zip: bytes, name: str, kind: str) -> None:
    resp = client_a.post("/v1/scenes", files=form(FIXTURES / name, images_zip))
    assert resp.status_code == 201, resp.text
    summary = resp.json()["summary"]
    assert summary["splat_format"] == kind and summary["gaussians"] == 21651 and summary["frames"] == 20


def test_checkpoint_and_unread_formats_are_refused_by_name(
    client_a: httpx.Client, images_zip: bytes, tmp_path: Path
) -> None:
    for name, expected in (
        ("ckpt_29999_rank0.pt", "does not accept checkpoints (.pt)"),
        ("scene.ksplat", "npx @playcanvas/splat-transform scene.ksplat point_cloud.ply"),
    ):
        (tmp_path / name).write_bytes(b"\0" * 64)
        resp = client_a.post("/v1/scenes", files=form(tmp_path / name, images_zip))
        assert resp.status_code == 422, resp.text
        assert expected in resp.json()["detail"]


def test_a_point_cloud_is_refused_with_what_it_is(
    client_a: httpx.Client, images_zip: bytes, tmp_path: Path
) -> None:
    """COLMAP's points3D as PLY (x y z, normals, colours) is not a splat: a 422 that says so and
    how to train one, not a splat-transform command that refuses the file."""
    from tests.core.scene.test_point_clouds import colmap_cloud

    resp = client_a.post("/v1/scenes", files=form(colmap_cloud(tmp_path / "point_cloud.ply"), images_zip))
    assert resp.status_code == 422, resp.text
    detail = resp.json()["detail"]
    assert "point_cloud.ply: a point cloud" in detail and "ns-train splatfacto" in detail, detail
    assert "splat-transform" not in detail and str(tmp_path) not in detail


def test_colmap_3_12_frames_and_rigs_upload(client_a: httpx.Client, tmp_path: Path) -> None:
    """Today's API refused this upload with "'frames.txt' is not a supported camera file"."""
    source = small_source_scene(tmp_path, sh_degree=1, centre=(0.3, -0.2, 1.0))
    sparse = tmp_path / "sparse"
    write_colmap_text(sparse, source.frames)
    (sparse / "rigs.txt").write_text("# Rig calib list with one line of data per calib:\n1 1 1 CAMERA\n")
    (sparse / "frames.txt").write_text("# Frame list with one line of data per frame:\n")
    write_ply(tmp_path / "point_cloud.ply", source.gaussians)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for frame in source.frames:
            zf.write(frame.image_path, Path(frame.image_path).name)
    cameras = [sparse / n for n in ("cameras.txt", "images.txt", "points3D.txt", "frames.txt", "rigs.txt")]
    resp = client_a.post("/v1/scenes", files=form(tmp_path / "point_cloud.ply", buf.getvalue(), cameras))
    assert resp.status_code == 201, resp.text
    assert resp.json()["summary"]["camera_format"] == "colmap"


def test_submit_reads_a_gsplat_result_dir_and_a_sog_folder(api: ApiServer, tmp_path: Path) -> None:
    source: SourceScene = small_source_scene(tmp_path, sh_degree=1, centre=(0.3, -0.2, 1.0))
    run = gsplat_run_folder(source, tmp_path / "work")  # the data lies beside the run, as trained
    local = resolve_layout(run, allow_source_path=True).splat_to_capture
    with BFieldsClient(api.base_url, api.keys["tenant-a"]) as client:
        summary = client.upload_scene(run)["summary"]
    assert summary["splat_format"] == "ply" and summary["gaussians"] == 300
    np.testing.assert_allclose(np.array(summary["splat_to_capture"]), local.matrix, atol=1e-6)

    folder = tmp_path / "sog_scene"
    shutil.copytree(SAMPLE / "images", folder / "images")
    shutil.copy(SAMPLE / "transforms.json", folder)
    for item in (FIXTURES / "tabletop_sog").iterdir():
        shutil.copy(item, folder / item.name)
    with BFieldsClient(api.base_url, api.keys["tenant-a"]) as client:
        summary = client.upload_scene(folder)["summary"]
    assert summary["splat_format"] == "sog" and summary["gaussians"] == 21651
