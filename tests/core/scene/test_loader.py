"""Scene folders: splat and camera discovery with their preference order, image checks, validation."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from PIL import Image

from bayesian_fields_core.checks.upload import validate_scene_folder
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.colmap import write_colmap_binary, write_colmap_text
from bayesian_fields_core.scene.inria import write_cameras_json
from bayesian_fields_core.scene.loader import find_cameras, find_splat, load_scene
from bayesian_fields_core.scene.nerfstudio import write_transforms
from bayesian_fields_core.scene.ply import write_ply

from .conftest import random_gaussians


def write_images(folder, frames, *, size=None):
    (folder / "images").mkdir(parents=True, exist_ok=True)
    for f in frames:
        Image.new("RGB", size or (f.width, f.height), (10, 20, 30)).save(folder / "images" / f.name)


def colmap_scene(folder, frames, *, binary=False):
    write_ply(folder / "point_cloud.ply", random_gaussians(100, 1))
    (write_colmap_binary if binary else write_colmap_text)(folder / "sparse" / "0", frames)
    write_images(folder, frames)


@pytest.mark.parametrize("binary", [False, True])
def test_load_colmap_scene_in_name_order(tmp_path, frames, binary):
    colmap_scene(tmp_path, frames, binary=binary)
    scene = load_scene(tmp_path)
    assert len(scene.gaussians) == 100 and scene.gaussians.sh_degree == 1
    assert [f.name for f in scene.frames] == ["frame_1.png", "frame_2.png", "frame_10.png"]
    assert all(f.image_path == tmp_path / "images" / f.name for f in scene.frames)
    assert scene.root == tmp_path


def test_camera_preference_order(tmp_path, frames):
    colmap_scene(tmp_path, frames)
    write_colmap_text(tmp_path / "sparse", frames[:1])
    write_cameras_json(tmp_path / "cameras.json", frames[:1])
    assert find_cameras(tmp_path) == ("colmap", tmp_path / "sparse" / "0")
    write_transforms(tmp_path / "transforms.json", [frames[0]])
    assert find_cameras(tmp_path)[0] == "transforms"
    (tmp_path / "transforms.json").unlink()
    for name in ("images.txt", "cameras.txt"):
        (tmp_path / "sparse" / "0" / name).unlink()
    assert find_cameras(tmp_path) == ("colmap", tmp_path / "sparse")
    for name in ("images.txt", "cameras.txt"):
        (tmp_path / "sparse" / name).unlink()
    assert find_cameras(tmp_path) == ("inria", tmp_path / "cameras.json")
    (tmp_path / "cameras.json").unlink()
    with pytest.raises(InputError, match="no cameras found"):
        find_cameras(tmp_path)


def test_splat_discovery(tmp_path):
    g = random_gaussians(5, 0, extra=False)
    for it in (7000, 30000, 900):
        (tmp_path / "point_cloud" / f"iteration_{it}").mkdir(parents=True)
        write_ply(tmp_path / "point_cloud" / f"iteration_{it}" / "point_cloud.ply", g)
    assert find_splat(tmp_path) == tmp_path / "point_cloud" / "iteration_30000" / "point_cloud.ply"
    write_ply(tmp_path / "scene.ply", g)  # a trained 3DGS iteration beats a stray top-level .ply
    assert find_splat(tmp_path) == tmp_path / "point_cloud" / "iteration_30000" / "point_cloud.ply"
    shutil.rmtree(tmp_path / "point_cloud")
    assert find_splat(tmp_path) == tmp_path / "scene.ply"
    write_ply(tmp_path / "other.ply", g)
    with pytest.raises(InputError, match="several splat files.*other.ply, scene.ply"):
        find_splat(tmp_path)
    write_ply(tmp_path / "splat.ply", g)
    assert find_splat(tmp_path) == tmp_path / "splat.ply"
    write_ply(tmp_path / "point_cloud.ply", g)
    assert find_splat(tmp_path) == tmp_path / "point_cloud.ply"
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no splat found"):
        find_splat(tmp_path / "empty")


def test_missing_images_are_listed(tmp_path, frames):
    colmap_scene(tmp_path, frames)
    (tmp_path / "images" / "frame_2.png").unlink()
    (tmp_path / "images" / "frame_10.png").unlink()
    with pytest.raises(
        InputError, match=r"sparse/0: 2 image files referenced by the cameras do not exist: .*frame_2\.png"
    ):
        load_scene(tmp_path)


@pytest.mark.parametrize(
    ("cameras", "listed"),
    [
        ("colmap-text", "sparse/0/images.txt"),
        ("colmap-binary", "sparse/0/images.bin"),
        ("transforms", "transforms.json"),
    ],
)
def test_missing_images_come_with_their_fix(tmp_path, frames, cameras, listed):
    """The refusal says what to do, naming the file that lists the frames (issue 45)."""
    if cameras == "transforms":
        write_ply(tmp_path / "point_cloud.ply", random_gaussians(100, 1))
        write_images(tmp_path, frames)
        for f in frames:
            f.image_path = tmp_path / "images" / f.name
        write_transforms(tmp_path / "transforms.json", frames)
    else:
        colmap_scene(tmp_path, frames, binary=cameras == "colmap-binary")
    (tmp_path / "images" / "frame_2.png").unlink()
    with pytest.raises(InputError) as refused:
        load_scene(tmp_path)
    message = str(refused.value)
    assert "frame_2.png" in message and "frame_1.png" not in message
    assert message.endswith(f"; restore those image files, or drop those frames from {listed}"), message


def test_transforms_scene_with_depth(tmp_path, frames):
    write_ply(tmp_path / "splat.ply", random_gaussians(10, 0))
    write_images(tmp_path, frames)
    for f in frames:
        f.image_path = tmp_path / "images" / f.name
        f.depth_path = tmp_path / "depth" / f.name
        f.depth_scale = 0.001
    write_transforms(tmp_path / "transforms.json", frames)
    with pytest.raises(InputError, match="3 depth files referenced by the cameras do not exist"):
        load_scene(tmp_path)
    (tmp_path / "depth").mkdir()
    for f in frames:
        Image.fromarray(np.full((f.height, f.width), 1234, np.uint16)).save(f.depth_path)
    summary = validate_scene_folder(tmp_path)
    assert summary["depth_frames"] == 3 and summary["camera_format"] == "transforms"
    scene = load_scene(tmp_path)
    assert [f.name for f in scene.frames] == [
        "images/frame_2.png",
        "images/frame_10.png",
        "images/frame_1.png",
    ]
    assert scene.frames[0].depth_scale == 0.001


def test_validate_summary_and_wrong_size_image(tmp_path, frames):
    colmap_scene(tmp_path, frames)
    summary = validate_scene_folder(tmp_path)
    # random_gaussians draws log-scales from N(0, 1): many are wider than the 4-unit scene
    assert [w for w in summary.pop("warnings") if "wider than the whole scene" in w]
    assert summary == {
        "splat": "point_cloud.ply",
        "gaussians": 100,
        "sh_degree": 1,
        "splat_format": "ply",
        "camera_format": "colmap",
        "camera_file": "sparse/0",
        "frames": 3,
        "image_size": [640, 480],
        "image_sizes": [[320, 240], [640, 480]],
        "distorted_frames": 0,
        "depth_frames": 0,
        "layout": "plain",
        "splat_to_capture": None,
    }
    Image.new("RGB", (100, 50)).save(tmp_path / "images" / "frame_10.png")
    with pytest.raises(
        InputError, match=r"frame_10\.png: image is 100x50 but its camera \(frame_10\.png\) is 640x480"
    ):
        validate_scene_folder(tmp_path)


def test_validate_reports_bad_splat_values(tmp_path, frames):
    colmap_scene(tmp_path, frames)
    g = random_gaussians(10, 0)
    g.opacity_logits[2] = np.nan
    write_ply(tmp_path / "point_cloud.ply", g)
    with pytest.raises(
        InputError, match=r"point_cloud\.ply: 1 non-finite values \(NaN or inf\): 1 in opacity"
    ):
        validate_scene_folder(tmp_path)
