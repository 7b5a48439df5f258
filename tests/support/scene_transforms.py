"""Misaligned copies of a scene folder for the alignment-check tests.

What a user gets when a trainer's frame transform is forgotten: the splat moved by a similarity
(scale, rotation, shift) against its cameras, cameras written in the OpenGL convention but read
as OpenCV, or photos that belong to other cameras. The splat is rewritten consistently: positions
x -> s R x + t, log-scales + log s, quaternions q -> R * q (normals rotated too); SH coefficients
above degree 0 are kept as they are (view-dependent colour is not rotated: the helper is for
frames' layout, not appearance).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from bayesian_fields_core.geometry.transforms import OPENGL_TO_OPENCV, quat_to_rotmat, rotmat_to_quat
from bayesian_fields_core.scene.nerfstudio import read_transforms, write_transforms
from bayesian_fields_core.scene.ply import read_ply, write_ply
from bayesian_fields_core.scene.similarity import Similarity
from bayesian_fields_core.scene.types import Gaussians


def transform_gaussians(
    g: Gaussians, *, scale: float = 1.0, rotation: np.ndarray | None = None, shift=(0.0, 0.0, 0.0)
) -> Gaussians:
    """The splat after x -> scale * R x + shift (R: (3, 3) rotation, identity by default)."""
    r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    means = scale * g.means.astype(np.float64) @ r.T + np.asarray(shift, dtype=np.float64)
    quats = rotmat_to_quat(r @ quat_to_rotmat(g.quats))
    extra = dict(g.extra)
    if all(k in extra for k in ("nx", "ny", "nz")):
        normals = np.stack([extra["nx"], extra["ny"], extra["nz"]], axis=1) @ r.T
        extra.update(nx=normals[:, 0], ny=normals[:, 1], nz=normals[:, 2])
        extra = {k: v.astype(g.extra[k].dtype) for k, v in extra.items()}
    return Gaussians(
        means=means.astype(np.float32),
        log_scales=(g.log_scales + np.float32(np.log(scale))).astype(np.float32),
        quats=quats.astype(np.float32),
        opacity_logits=g.opacity_logits,
        sh=g.sh,
        extra=extra,
    )


def rotation_z(degrees: float) -> np.ndarray:
    a = np.deg2rad(degrees)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


def copy_scene(src: Path, dst: Path) -> Path:
    """A copy of a scene folder with transforms.json as its only camera file (sparse/ dropped, so
    every loader reads the cameras the helpers below rewrite)."""
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("sparse", ".bfields"))
    if not (dst / "transforms.json").is_file():
        raise FileNotFoundError(f"{src} has no transforms.json")
    return dst


def splat_path(folder: Path) -> Path:
    for name in ("point_cloud.ply", "splat.ply"):
        if (folder / name).is_file():
            return folder / name
    raise FileNotFoundError(f"no splat in {folder}")


def move_splat(
    folder: Path, *, scale: float = 1.0, rotation: np.ndarray | None = None, shift=(0, 0, 0)
) -> Path:
    """Rewrite the folder's splat in place by a similarity transform; returns the folder."""
    path = splat_path(folder)
    write_ply(path, transform_gaussians(read_ply(path), scale=scale, rotation=rotation, shift=shift))
    return folder


def flip_camera_convention(folder: Path) -> Path:
    """Rewrite transforms.json as if its OpenCV camera-to-world matrices had been written where
    OpenGL ones belong: each camera's y and z axes are flipped (it looks backwards)."""
    path = folder / "transforms.json"
    data = json.loads(path.read_text(encoding="utf-8"))
    for frame in data["frames"]:
        frame["transform_matrix"] = (np.asarray(frame["transform_matrix"]) @ OPENGL_TO_OPENCV).tolist()
    path.write_text(json.dumps(data, indent=2), encoding="utf-8")
    return folder


def shuffle_images(folder: Path, *, shift: int | None = None) -> Path:
    """Give every camera another camera's photo (a cyclic shift by half the capture): the
    'wrong images folder' case, with images that still decode and have the right size."""
    images = sorted((folder / "images").iterdir())
    k = len(images) // 2 if shift is None else shift
    data = [p.read_bytes() for p in images]
    for i, p in enumerate(images):
        p.write_bytes(data[(i + k) % len(images)])
    return folder


def similar_scene(src: Path, dst: Path, sim: Similarity) -> Path:
    """A copy of the scene folder `src` with the whole scene moved by `sim`: the splat (positions,
    rotations, log-scales and SH bands, `Similarity.gaussians`) and the cameras together, so the
    photos still match. What a user gets from the same capture in other units, axes or origin
    (COLMAP's frame is arbitrary). Cameras stay rigid: a camera point x_c maps to s x_c, i.e.
    world_to_camera' = [R_wc R^T | s t_wc - R_wc R^T t]. Returns `dst`."""
    copy_scene(src, dst)
    path = splat_path(dst)
    write_ply(path, sim.gaussians(read_ply(path)))
    frames = read_transforms(dst / "transforms.json")
    rt = sim.rotation.T
    for frame in frames:
        w2c = np.asarray(frame.world_to_camera, dtype=np.float64)
        moved = np.eye(4)
        moved[:3, :3] = w2c[:3, :3] @ rt
        moved[:3, 3] = sim.scale * w2c[:3, 3] - w2c[:3, :3] @ rt @ sim.translation
        frame.world_to_camera = moved
    write_transforms(dst / "transforms.json", frames)
    return dst
