"""Trainers' output folders submitted to the real API as they are (client -> HTTP -> S3 -> the
server's validator): the splat's frame reaches the service, and the server resolves the same
splat -> cameras similarity as `bfields run` does locally."""

from __future__ import annotations

from pathlib import Path

import httpx
import numpy as np
import pytest

from bayesian_fields_core.scene.layout import resolve_layout
from bayesian_fields_service.client import BFieldsClient
from tests.core.scene.trainer_layouts import SourceScene, inria_output, small_source_scene, splatfacto_output
from tests.integration.fixtures.services import ApiServer
from tests.services.conftest import scene_form

pytestmark = pytest.mark.integration


@pytest.fixture
def source(tmp_path: Path) -> SourceScene:
    """300 Gaussians in front of 3 cameras, 64x48 images, in the scene's world frame."""
    return small_source_scene(tmp_path, sh_degree=1, centre=(0.0, 0.0, 0.0))


def test_splatfacto_folder_uploads_with_its_frame(
    api: ApiServer, source: SourceScene, tmp_path: Path
) -> None:
    folder = splatfacto_output(source, tmp_path / "ns")
    local = resolve_layout(folder).splat_to_capture
    assert local is not None and not local.is_identity
    with BFieldsClient(api.base_url, api.keys["tenant-a"]) as client:
        scene = client.upload_scene(folder)
    summary = scene["summary"]
    assert summary["layout"] == "matrix"  # the client sends the resolved similarity
    np.testing.assert_allclose(np.array(summary["splat_to_capture"]), local.matrix, atol=1e-9)
    assert summary["frames"] == 3 and summary["gaussians"] == 300


def test_inria_output_with_images_in_source_path(api: ApiServer, source: SourceScene, tmp_path: Path) -> None:
    """cfg_args names the dataset outside the output folder: the client (the user's own machine)
    follows it and uploads those images; the server reads only the upload."""
    out = inria_output(source, tmp_path / "output" / "run1", tmp_path / "dataset")
    with BFieldsClient(api.base_url, api.keys["tenant-a"]) as client:
        scene = client.upload_scene(out)
    summary = scene["summary"]
    assert summary["camera_format"] == "inria" and summary["frames"] == 3
    assert summary["gaussians"] == 300  # iteration_30000, never input.ply or iteration_7000
    assert summary["splat_to_capture"] is None


def test_unknown_transform_file_is_refused(client_a: httpx.Client, scene_dir: Path, tmp_path: Path) -> None:
    form = scene_form(scene_dir)
    form.append(("transform", ("transforms_of_mine.json", b'{"splat_to_camera": [[1,0,0,0]]}')))
    resp = client_a.post("/v1/scenes", files=form)
    assert resp.status_code == 422, resp.text
    assert "dataparser_transforms.json" in resp.text  # names what it accepts


def test_bad_transform_matrix_is_refused(client_a: httpx.Client, scene_dir: Path) -> None:
    form = scene_form(scene_dir)
    form.append(("transform", ("splat_transform.json", b'{"splat_to_camera": [[1, 0], [0, 1]]}')))
    resp = client_a.post("/v1/scenes", files=form)
    assert resp.status_code == 422, resp.text
    assert "splat_transform.json" in resp.text
