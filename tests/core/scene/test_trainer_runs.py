"""Trainers' run folders read as they are: a gsplat result_dir (cfg.yml, ckpts/, the COLMAP
data it names, the world normalisation recomputed) and a nerfstudio run (config.yml with its
data path, dataparser_transforms.json, the exported splat under exports/)."""

from __future__ import annotations

import json
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from bayesian_fields_core.checks.upload import validate_scene_folder
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.geometry.transforms import invert_rigid
from bayesian_fields_core.scene.colmap import read_colmap_points, write_colmap_binary
from bayesian_fields_core.scene.gsplat_normalise import gsplat_world_to_splat
from bayesian_fields_core.scene.loader import load_scene
from bayesian_fields_core.scene.types import Frame

from .format_writers import write_gsplat_checkpoint
from .test_layouts import assert_same_scene
from .trainer_layouts import (
    SourceScene,
    gsplat_normalisation,
    small_source_scene,
    splatfacto_output,
    write_trainer_ply,
)

GSPLAT_CFG = """\
batch_size: 1
data_dir: {data_dir}
data_factor: {factor}
normalize_world_space: {normalize}
result_dir: {result_dir}
strategy: !!python/object:gsplat.strategy.default.DefaultStrategy
  absgrad: false
  prune_opa: 0.005
  refine_every: 100
test_every: 8
"""


def write_points3d_bin(sparse: Path, points: np.ndarray) -> None:
    """COLMAP points3D.bin: count, then per point id, xyz, rgb, error, an empty track."""
    body = [struct.pack("<Q", len(points))]
    body += [struct.pack("<Q3d3BdQ", i + 1, *p, 128, 128, 128, 0.5, 0) for i, p in enumerate(points)]
    (sparse / "points3D.bin").write_bytes(b"".join(body))


@pytest.fixture
def source(tmp_path: Path) -> SourceScene:
    return small_source_scene(tmp_path, sh_degree=1, centre=(0.3, -0.2, 1.0))


def gsplat_run_folder(
    src: SourceScene, root: Path, *, factor: int = 1, normalize: bool = True, ckpt: bool = True
) -> Path:
    """`python simple_trainer.py default --data_dir data/garden --result_dir results/garden`:
    the dataset under root/data/garden, the run under root/results/garden (no transform file)."""
    data = root / "data" / "garden"
    images = data / ("images" if factor == 1 else f"images_{factor}")
    images.mkdir(parents=True)
    frames = []
    for f in src.frames:
        name = Path(f.image_path).name
        Image.open(f.image_path).resize((f.width // factor, f.height // factor)).save(images / name)
        frames.append(
            Frame(name, f.K.copy(), f.world_to_camera.copy(), f.width, f.height, image_path=images / name)
        )
    write_colmap_binary(data / "sparse" / "0", frames)
    points = src.gaussians.means.astype(np.float64)
    write_points3d_bin(data / "sparse" / "0", points)
    transform = gsplat_normalisation(frames, points) if normalize else None
    splat = transform.gaussians(src.gaussians) if transform else src.gaussians
    run = root / "results" / "garden"
    run.mkdir(parents=True)
    (run / "cfg.yml").write_text(
        GSPLAT_CFG.format(
            data_dir="data/garden",
            factor=factor,
            normalize=str(normalize).lower(),
            result_dir="results/garden",
        )
    )
    if ckpt:
        write_gsplat_checkpoint(run / "ckpts" / "ckpt_6999_rank0.pt", splat.subset(np.arange(10)), step=6999)
        write_gsplat_checkpoint(run / "ckpts" / "ckpt_29999_rank0.pt", splat)
    else:
        write_trainer_ply(run / "ply" / "point_cloud_29999.ply", splat, normals=False)
    return run


def ring_of_cameras(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 4, 4) OpenCV camera-to-world poses on a tilted ring, looking at a point near the origin."""
    poses = []
    for i in range(n):
        angle = 2 * np.pi * i / n
        eye = np.array([3 * np.cos(angle), 3 * np.sin(angle), 1.0 + 0.3 * rng.standard_normal()])
        target = rng.normal(0.0, 0.1, 3)
        z = (target - eye) / np.linalg.norm(target - eye)
        x = np.cross(z, [0.0, 0.0, -1.0])
        x /= np.linalg.norm(x)
        pose = np.eye(4)
        pose[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
        pose[:3, 3] = eye
        poses.append(pose)
    return np.stack(poses)


def test_normalisation_matches_an_independent_reimplementation() -> None:
    """The library's maths against the test suite's own reading of gsplat's Parser, on a scene
    with a floor and objects, moved by an arbitrary similarity (so no step is an identity)."""
    rng = np.random.default_rng(3)
    c2w = ring_of_cameras(12, rng)
    floor = np.c_[rng.uniform(-2, 2, (800, 2)), rng.normal(0, 0.01, 800)]
    objects = rng.normal([0.3, -0.2, 0.4], [0.4, 0.2, 0.3], (200, 3))
    points = np.vstack([floor, objects])
    turn = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    turn *= np.sign(np.linalg.det(turn))
    world = np.eye(4)
    world[:3, :3], world[:3, 3] = 2.5 * turn, [4.0, -1.0, 7.0]
    moved_c2w = world @ c2w
    moved_c2w[:, :3, :3] /= 2.5
    moved_points = points @ world[:3, :3].T + world[:3, 3]
    frames = [Frame(f"{i}.png", np.eye(3), invert_rigid(p), 10, 10) for i, p in enumerate(moved_c2w)]

    ours = gsplat_world_to_splat(moved_c2w, moved_points)
    reference = gsplat_normalisation(frames, moved_points)
    np.testing.assert_allclose(ours.matrix, reference.matrix, atol=1e-9)
    # What the normalisation promises: unit median camera distance from the focus, the floor's
    # normal along z with most points below the mean height, principal axes along x, y, z.
    normalised = ours.points(moved_points)
    cov = np.cov(normalised, rowvar=False)
    assert np.abs(cov - np.diag(np.diag(cov))).max() < 1e-9
    assert np.diag(cov)[0] >= np.diag(cov)[1] >= np.diag(cov)[2]
    assert np.median(normalised[:, 2]) <= np.mean(normalised[:, 2])


def test_gsplat_result_dir_as_the_trainer_leaves_it(tmp_path: Path, source: SourceScene) -> None:
    run = gsplat_run_folder(source, tmp_path)
    assert len(read_colmap_points(tmp_path / "data" / "garden" / "sparse" / "0")) == len(source.gaussians)
    scene = load_scene(run, allow_source_path=True)  # the CLI: data_dir lies beside the run
    assert scene.layout == "gsplat" and scene.splat_path == run / "ckpts" / "ckpt_29999_rank0.pt"
    assert_same_scene(scene, source, transformed=True)  # the splat lands on its cameras
    # `bfields run results/garden/cfg.yml` names the same run
    assert_same_scene(load_scene(run / "cfg.yml", allow_source_path=True), source, transformed=True)
    # an upload never follows data_dir out of the uploaded folder
    with pytest.raises(
        InputError, match=r"cfg.yml: the data folder 'data/garden' lies outside the uploaded folder"
    ):
        validate_scene_folder(run)


def test_gsplat_ply_and_data_factor_and_no_normalisation(tmp_path: Path, source: SourceScene) -> None:
    run = gsplat_run_folder(source, tmp_path / "a", factor=2, ckpt=False)
    scene = load_scene(run, allow_source_path=True)
    assert scene.splat_path == run / "ply" / "point_cloud_29999.ply"
    np.testing.assert_allclose(scene.gaussians.means, source.gaussians.means, atol=2e-5)
    assert all(f.width == 32 and f.image_path.parent.name == "images_2" for f in scene.frames)
    run = gsplat_run_folder(source, tmp_path / "b", normalize=False)
    assert_same_scene(load_scene(run, allow_source_path=True), source, transformed=False)


def test_gsplat_run_with_its_data_inside_uploads(tmp_path: Path, source: SourceScene) -> None:
    run = gsplat_run_folder(source, tmp_path)
    shutil.move(tmp_path / "data", run / "data")
    summary = validate_scene_folder(run)
    assert summary["layout"] == "gsplat" and summary["splat_format"] == "checkpoint"
    assert summary["camera_file"] == "data/garden/sparse/0"


def test_nerfstudio_run_folder_with_config_and_export(tmp_path: Path, source: SourceScene) -> None:
    data = splatfacto_output(source, tmp_path / "data" / "poster")
    run = tmp_path / "outputs" / "poster" / "splatfacto" / "2026-01-01_000000"
    (run / "exports" / "splat").mkdir(parents=True)
    shutil.move(data / "splat.ply", run / "exports" / "splat" / "splat.ply")
    shutil.move(data / "dataparser_transforms.json", run / "dataparser_transforms.json")
    (run / "config.yml").write_text(
        "!!python/object:nerfstudio.engine.trainer.TrainerConfig\n"
        "data: !!python/object/apply:pathlib.PosixPath\n- data\n- poster\n"
        "experiment_name: poster\nmethod_name: splatfacto\n"
    )
    for target in (run, run / "config.yml"):
        scene = load_scene(target, allow_source_path=True)
        assert scene.layout == "nerfstudio" and scene.splat_path.name == "splat.ply"
        assert_same_scene(scene, source, transformed=True)
    (run / "exports" / "splat" / "splat.ply").unlink()
    with pytest.raises(InputError, match="ns-export gaussian-splat --load-config"):
        load_scene(run, allow_source_path=True)


def test_ns_process_data_colmap_folder_is_found(tmp_path: Path, source: SourceScene) -> None:
    data = splatfacto_output(source, tmp_path / "poster", cameras="colmap")
    (data / "colmap").mkdir()
    shutil.move(data / "sparse", data / "colmap" / "sparse")
    scene = load_scene(data)
    assert_same_scene(scene, source, transformed=True)
    assert json.loads((data / "dataparser_transforms.json").read_text())["scale"] > 0
