"""Each trainer's output folder, laid out as the trainer writes it, loads into the untransformed
scene: same Gaussians (in the cameras' frame), same cameras; and what does not line up is refused."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from bayesian_fields_core.checks.upload import validate_scene_folder
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.inria_output import read_cfg_args
from bayesian_fields_core.scene.loader import find_splat, load_scene, resolve_layout
from bayesian_fields_core.scene.ply import write_ply
from bayesian_fields_core.scene.similarity import Similarity
from bayesian_fields_core.scene.types import Frame, Scene

from .trainer_layouts import (
    SourceScene,
    gsplat_output,
    inria_output,
    scene_yaml_output,
    small_source_scene,
    splatfacto_output,
)


@pytest.fixture
def source(tmp_path: Path) -> SourceScene:
    """A small scene in its world frame: 300 Gaussians (SH degree 2), 3 cameras, 64x48 images."""
    return small_source_scene(tmp_path, sh_degree=2, centre=(0.3, -0.2, 1.0))


def assert_same_scene(scene: Scene, src: SourceScene, *, transformed: bool) -> None:
    np.testing.assert_allclose(scene.gaussians.means, src.gaussians.means, atol=2e-5)
    np.testing.assert_allclose(scene.gaussians.log_scales, src.gaussians.log_scales, atol=2e-5)
    np.testing.assert_allclose(scene.gaussians.sh, src.gaussians.sh, atol=1e-4)
    q, q0 = scene.gaussians.quats, src.gaussians.quats
    sign = np.sign((q * q0).sum(axis=1, keepdims=True))  # q and -q are one rotation
    np.testing.assert_allclose(q * sign, q0, atol=1e-4)
    by_stem = {Path(f.name).stem: f for f in src.frames}
    assert len(scene.frames) == len(src.frames)
    for frame in scene.frames:
        ref = by_stem[Path(frame.name).stem]
        np.testing.assert_allclose(frame.world_to_camera, ref.world_to_camera, atol=1e-6)
        np.testing.assert_allclose(frame.K, ref.K, atol=1e-6)
        assert (frame.width, frame.height) == (ref.width, ref.height)
    assert (scene.splat_to_capture is not None) == transformed


def test_inria_output_folder_as_3dgs_writes_it(tmp_path: Path, source: SourceScene) -> None:
    out = inria_output(source, tmp_path / "output" / "run", tmp_path / "dataset")
    assert (out / "input.ply").is_file() and (out / "point_cloud" / "iteration_7000").is_dir()
    assert find_splat(out) == out / "point_cloud" / "iteration_30000" / "point_cloud.ply"
    # Images only at cfg_args' source_path, outside the folder: the service refuses, the CLI follows.
    with pytest.raises(
        InputError, match=r"cfg_args: .*source_path .*outside.*copy images/ into the scene folder"
    ):
        load_scene(out)
    scene = load_scene(out, allow_source_path=True)
    assert scene.layout == "inria"
    assert_same_scene(scene, source, transformed=False)
    # Copied beside the output folder, no source_path is needed (what an upload does).
    (tmp_path / "dataset" / "images").rename(out / "images")
    assert_same_scene(load_scene(out), source, transformed=False)


def test_inria_input_ply_is_never_the_splat(tmp_path: Path, source: SourceScene) -> None:
    out = inria_output(source, tmp_path / "run", tmp_path / "dataset")
    import shutil

    shutil.rmtree(out / "point_cloud")
    with pytest.raises(InputError, match="input.ply is 3DGS's SfM point cloud, not a splat"):
        find_splat(out)


@pytest.mark.slow
def test_inria_cameras_json_rescaled_to_the_images(tmp_path: Path, source: SourceScene) -> None:
    """Images twice the camera size (3DGS -r 2 against the full-size images, or images_2 vs the
    COLMAP size) get K doubled; a size 3DGS cannot produce is refused naming both sizes."""
    out = inria_output(source, tmp_path / "run", tmp_path / "dataset")
    (out / "images").mkdir()
    for f in source.frames:
        Image.new("RGB", (128, 96)).save(out / "images" / f.name)
    scene = load_scene(out)
    for frame, ref in zip(sorted(scene.frames, key=lambda f: f.name), source.frames, strict=True):
        assert (frame.width, frame.height) == (128, 96)
        np.testing.assert_allclose(frame.K, np.diag([2.0, 2.0, 1.0]) @ ref.K, atol=1e-9)
    # 3DGS's automatic resize: images wider than 1600 px trained at 1600 wide.
    frames = json.loads((out / "cameras.json").read_text())
    for entry in frames:
        entry["width"], entry["height"], entry["fx"], entry["fy"] = 1600, 1200, 1500.0, 1500.0
    (out / "cameras.json").write_text(json.dumps(frames))
    for f in source.frames:
        Image.new("RGB", (4000, 3000)).save(out / "images" / f.name)
    scene = load_scene(out)
    assert (scene.frames[0].width, scene.frames[0].height) == (4000, 3000)
    np.testing.assert_allclose(scene.frames[0].K[:2, :], [[3750.0, 0, 2000.0], [0, 3750.0, 1500.0]])
    Image.new("RGB", (4000, 2000)).save(out / "images" / source.frames[1].name)
    with pytest.raises(
        InputError,
        match=r"cameras.json: image frame_00001.png is 4000x2000 but its camera in cameras.json is 1600x1200",
    ):
        load_scene(out)


def test_cfg_args_is_parsed_never_evaluated(tmp_path: Path) -> None:
    good = tmp_path / "cfg_args"
    good.write_text("Namespace(images='images_4', resolution=2, source_path='/data/garden', eval=True)")
    assert read_cfg_args(good) == {
        "images": "images_4",
        "resolution": 2,
        "source_path": "/data/garden",
        "eval": True,
    }
    marker = tmp_path / "pwned"
    for text in (
        f"Namespace(images=__import__('os').system('touch {marker}'))",
        f"__import__('os').system('touch {marker}')",
        "Namespace(**{'a': 1})",
        "Namespace(",
    ):
        good.write_text(text)
        with pytest.raises(InputError, match="cfg_args"):
            read_cfg_args(good)
    assert not marker.exists()


def test_inria_images_folder_named_by_cfg_args_must_stay_inside(tmp_path: Path, source: SourceScene) -> None:
    out = inria_output(source, tmp_path / "run", tmp_path / "dataset", images="../../dataset/images")
    with pytest.raises(InputError, match="images folder path .* leaves the scene folder"):
        load_scene(out, allow_source_path=False)


@pytest.mark.parametrize("cameras", ["transforms", "colmap"])
def test_splatfacto_export_with_dataparser_transforms(
    tmp_path: Path, source: SourceScene, cameras: str
) -> None:
    out = splatfacto_output(source, tmp_path / "ns", cameras=cameras)
    assert find_splat(out) == out / "splat.ply"
    scene = load_scene(out)
    assert scene.layout == "nerfstudio"
    assert_same_scene(scene, source, transformed=True)
    # Without the dataparser transform the splat is in another frame: not the scene.
    (out / "dataparser_transforms.json").rename(tmp_path / "elsewhere.json")
    raw = load_scene(out)
    assert raw.splat_to_capture is None
    assert np.abs(raw.gaussians.means - source.gaussians.means).max() > 0.1
    # Given by path (CLI --splat-transform) instead of found beside the splat.
    assert_same_scene(load_scene(out, splat_transform=tmp_path / "elsewhere.json"), source, transformed=True)


def test_gsplat_normalised_splat_with_its_transform(tmp_path: Path, source: SourceScene) -> None:
    data = gsplat_output(source, tmp_path / "garden")
    assert find_splat(data) == data / "ply" / "point_cloud_29999.ply"
    scene = load_scene(data)
    assert scene.layout == "gsplat"
    assert_same_scene(scene, source, transformed=True)
    summary = validate_scene_folder(data)
    assert summary["layout"] == "gsplat" and summary["splat"] == "ply/point_cloud_29999.ply"
    np.testing.assert_allclose(np.asarray(summary["splat_to_capture"]), scene.splat_to_capture.matrix)


def test_scene_yaml_names_everything(tmp_path: Path, source: SourceScene) -> None:
    sim = Similarity(
        2.0, np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), np.array([1.0, 2.0, 3.0])
    )
    out = scene_yaml_output(source, tmp_path / "any", sim)
    scene = load_scene(out)
    assert scene.layout == "scene.yaml"
    assert_same_scene(scene, source, transformed=True)
    np.testing.assert_allclose(scene.splat_to_capture.matrix, sim.matrix, atol=1e-12)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("splat: ../outside.ply\ncameras: recon/0\n", "splat path '../outside.ply' leaves the scene folder"),
        ("splat: exports/model.ply\ncameras: /etc\n", "cameras path '/etc' is absolute"),
        (
            "splat: exports/model.ply\ncameras: recon/0\nimages: ../src\n",
            "images folder path '../src' leaves",
        ),
        (
            "splat: exports/model.ply\ncameras: recon/0\ncolour: red\n",
            "colour: Extra inputs are not permitted",
        ),
        ("splat: exports/model.ply\n", "cameras: Field required"),
        (
            "splat: exports/model.ply\ncameras: recon/0\nsplat_to_camera: [[1, 0, 0, 0], [0, 2, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n",
            "not a similarity",
        ),
        (
            "splat: exports/model.ply\ncameras: recon/0\nimages: photos\ndepth: depth\n",
            "3 depth maps are missing: depth/frame_00000",
        ),
    ],
)
def test_scene_yaml_is_validated(tmp_path: Path, source: SourceScene, content: str, message: str) -> None:
    out = scene_yaml_output(source, tmp_path / "any", Similarity.identity())
    (out / "scene.yaml").write_text(content)
    (tmp_path / "outside.ply").write_bytes(b"")
    with pytest.raises(InputError, match=f"scene.yaml.*{message}"):
        load_scene(out)


def test_scene_yaml_depth_folder(tmp_path: Path, source: SourceScene) -> None:
    out = scene_yaml_output(source, tmp_path / "any", Similarity.identity())
    (out / "depth").mkdir()
    for f in source.frames:
        np.save(out / "depth" / f"{Path(f.name).stem}.npy", np.ones((48, 64), np.float32))
    (out / "scene.yaml").write_text(
        "splat: exports/model.ply\ncameras: recon/0\nimages: photos\ndepth: depth\ndepth_scale: 0.5\n"
    )
    scene = load_scene(out)
    assert all(f.depth_path == (out / "depth" / f"{Path(f.name).stem}.npy").resolve() for f in scene.frames)
    assert all(f.depth_scale == 0.5 for f in scene.frames)


def test_plain_folder_is_unchanged(tmp_path: Path, source: SourceScene) -> None:
    from bayesian_fields_core.scene.colmap import write_colmap_text

    folder = tmp_path / "plain"
    (folder / "images").mkdir(parents=True)
    frames = []
    for f in source.frames:
        Image.open(f.image_path).save(folder / "images" / f.name)
        frames.append(Frame(f.name, f.K, f.world_to_camera, f.width, f.height))
    write_colmap_text(folder / "sparse" / "0", frames)
    write_ply(folder / "point_cloud.ply", source.gaussians)
    layout = resolve_layout(folder)
    assert (layout.trainer, layout.camera_kind, layout.splat_to_capture) == ("plain", "colmap", None)
    assert_same_scene(load_scene(folder), source, transformed=False)


def test_images_smaller_than_cameras_json(tmp_path: Path, source: SourceScene) -> None:
    """3DGS -i images_2 against a full-size COLMAP model: cameras.json is twice the images."""
    out = inria_output(source, tmp_path / "run", tmp_path / "dataset", images="images_2")
    (out / "images_2").mkdir()
    for f in source.frames:
        Image.new("RGB", (32, 24)).save(out / "images_2" / f.name)
    scene = load_scene(out)
    assert {(f.width, f.height) for f in scene.frames} == {(32, 24)}
    np.testing.assert_allclose(scene.frames[0].K, np.diag([0.5, 0.5, 1.0]) @ source.frames[0].K, atol=1e-9)


def test_transform_files_are_checked(tmp_path: Path) -> None:
    from bayesian_fields_core.scene.trainer_transforms import (
        LEGACY_COLMAP_APPLIED_TRANSFORM,
        nerfstudio_to_transforms_frame,
        read_transform_file,
    )

    path = tmp_path / "t.json"
    cases = {
        '{"transform": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]}': "no 'scale'",
        '{"transform": [[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0]], "scale": 1}': "must be rigid",
        '{"transform": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]], "scale": -1}': "positive",
        '{"camera_to_splat": [[1, 0], [0, 1]]}': "4x4",
        '{"splat_to_camera": 1, "camera_to_splat": 2}': "exactly one",
        "[1, 2]": "JSON object",
    }
    for text, message in cases.items():
        path.write_text(text)
        with pytest.raises(InputError, match=message):
            read_transform_file(path)
    # nerfstudio's legacy rule: a COLMAP-made dataset without the field used this applied_transform.
    (tmp_path / "colmap" / "sparse" / "0").mkdir(parents=True)
    (tmp_path / "transforms.json").write_text('{"frames": [], "applied_scale": 2.0}')
    applied, applied_scale = nerfstudio_to_transforms_frame(tmp_path / "transforms.json")
    np.testing.assert_allclose(applied.matrix[:3], LEGACY_COLMAP_APPLIED_TRANSFORM)
    assert applied_scale == 2.0
