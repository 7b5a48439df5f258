"""A gsplat scene uploaded through /ui as a person has it: the normalised splat gsplat trained
(here as the `.splat` a web viewer
would be given), the COLMAP model, the images, and the
`splat_transform.json` holding gsplat's `camera_to_splat`; the job runs on the real stack and
succeeds, with the splat mapped onto its cameras."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest

from bayesian_fields_core.scene.colmap import read_colmap
from bayesian_fields_core.scene.formats.antimatter import write_antimatter
from bayesian_fields_core.scene.gsplat_normalise import gsplat_world_to_splat
from bayesian_fields_core.scene.ply import read_ply
from tests.integration.fixtures.services import ApiServer

pytestmark = [pytest.mark.integration, pytest.mark.slow]

SAMPLE = Path(__file__).resolve().parents[4] / "samples" / "tabletop"
TASKS = ["get the orange cone"]
JOB_TIMEOUT_MS = 600_000


def gsplat_scene(tmp: Path) -> tuple[Path, Path, Path]:
    """(normalised splat, transform file, images zip) of the sample as gsplat leaves it."""
    frames = read_colmap(SAMPLE / "sparse" / "0", SAMPLE / "images")
    gaussians = read_ply(SAMPLE / "point_cloud.ply")
    world_to_splat = gsplat_world_to_splat(
        np.stack([f.camera_to_world for f in frames]), gaussians.means[::10].astype(np.float64)
    )
    splat = tmp / "garden.splat"
    write_antimatter(splat, world_to_splat.gaussians(gaussians))
    transform = tmp / "splat_transform.json"
    transform.write_text(json.dumps({"camera_to_splat": world_to_splat.matrix.tolist()}))
    images = tmp / "images.zip"
    with zipfile.ZipFile(images, "w") as zf:
        for image in sorted((SAMPLE / "images").iterdir()):
            zf.write(image, image.name)
    return splat, transform, images


def test_ui_uploads_a_gsplat_scene_with_its_transform(
    api_server: ApiServer,
    ui_workers,
    browser,
    tmp_path: Path,  # noqa: ANN001
) -> None:
    api = api_server
    splat, transform, images = gsplat_scene(tmp_path)
    page = browser.new_context(viewport={"width": 1200, "height": 900}).new_page()
    page.goto(f"{api.base_url}/ui/")
    page.fill("#api-key", api.keys["tenant-a"])
    page.click("#login")
    page.wait_for_selector("#app:not(.hidden)")
    assert "splat_transform.json" in page.text_content("label[for='transform']")
    page.fill("#scene-name", "gsplat-tabletop")
    page.set_input_files("#splat", str(splat))
    page.set_input_files(
        "#cameras", [str(SAMPLE / "sparse" / "0" / n) for n in ("cameras.txt", "images.txt")]
    )
    page.set_input_files("#images", str(images))
    page.set_input_files("#transform", str(transform))
    page.fill("#upload-tasks", "\n".join(TASKS))
    page.click("#upload")
    page.wait_for_function(
        "document.getElementById('upload-status').textContent.includes('submitted') || "
        "document.querySelector('#upload-status .error') !== null",
        timeout=180_000,
    )
    status = page.text_content("#upload-status")
    assert "submitted" in status, status
    scene_id = status.split("scene ")[1].split()[0]
    job_id = status.split("job ")[1].split()[0]
    summary = httpx.get(f"{api.base_url}/v1/scenes/{scene_id}", headers=api.headers("tenant-a")).json()[
        "summary"
    ]
    assert summary["layout"] == "gsplat" and summary["camera_format"] == "colmap"
    splat_to_camera = np.array(summary["splat_to_capture"])
    assert abs(np.linalg.det(splat_to_camera[:3, :3]) ** (1 / 3) - 1.0) > 0.05  # a real rescale
    page.wait_for_selector(f"tr[data-job='{job_id}'][data-state='succeeded']", timeout=JOB_TIMEOUT_MS)
    result = httpx.get(f"{api.base_url}/v1/jobs/{job_id}/result", headers=api.headers("tenant-a"))
    assert result.status_code == 200, result.text
