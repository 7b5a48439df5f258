"""Builders of scene folders laid out exactly as each trainer writes them, from one synthetic scene.

Each takes the untransformed scene (Gaussians and OpenCV frames in its world frame, images on
disk) and writes what the trainer would have produced from it, with the trainer's own file names,
property order, frame and conventions (read from their sources):

- INRIA 3DGS (`train.py`): `cfg_args` (str of an argparse Namespace), `cameras.json`
  (`camera_to_JSON`: c2w rotation rows + centre, centred principal point, `img_name` without
  extension), `input.ply` (SfM points: x y z nx ny nz red green blue), and
  `point_cloud/iteration_<N>/point_cloud.ply` at several N; the dataset (images/, sparse/0) in a
  separate source folder. No world normalisation.
- nerfstudio splatfacto (`ns-process-data` + `ns-train splatfacto` + `ns-export gaussian-splat`):
  transforms.json (OpenGL c2w) with `applied_transform`; the dataparser's "up" orientation and
  "poses" centring + auto scale; `dataparser_transforms.json` {"transform": 3x4, "scale"} mapping
  the original frame to the internal one; `splat.ply` in the internal frame with nerfstudio's
  header comments and property order.
- gsplat `simple_trainer` (`normalize_world_space=True`): COLMAP dataset; `parser.transform` =
  (flip) @ PCA @ similarity_from_cameras; `ply/point_cloud_<step>.ply` in the normalised frame
  (no normals), and the user's `splat_transform.json` {"camera_to_splat": 4x4}.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from bayesian_fields_core.geometry.transforms import OPENGL_TO_OPENCV, invert_rigid
from bayesian_fields_core.scene.colmap import write_colmap_binary
from bayesian_fields_core.scene.inria import write_cameras_json
from bayesian_fields_core.scene.nerfstudio import write_transforms
from bayesian_fields_core.scene.similarity import Similarity
from bayesian_fields_core.scene.types import Frame, Gaussians

NS_PROCESS_DATA_APPLIED = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0]])
"""ns-process-data's COLMAP -> transforms.json world change (colmap_utils.colmap_to_json)."""


@dataclass
class SourceScene:
    """The untransformed scene: Gaussians and frames in one world frame, images on disk."""

    gaussians: Gaussians
    frames: list[Frame]


def write_trainer_ply(path: Path, g: Gaussians, *, normals: bool, comments: tuple[str, ...] = ()) -> None:
    """A binary little-endian splat in the trainers' common property order
    (x y z [nx ny nz] f_dc_* f_rest_* opacity scale_* rot_*), f_rest channel-major, float32."""
    n, k = len(g), g.sh.shape[1]
    cols: list[tuple[str, np.ndarray]] = [(a, g.means[:, i]) for i, a in enumerate("xyz")]
    if normals:
        cols += [(a, np.zeros(n, np.float32)) for a in ("nx", "ny", "nz")]
    cols += [(f"f_dc_{c}", g.sh[:, 0, c]) for c in range(3)]
    rest = g.sh[:, 1:, :].transpose(0, 2, 1).reshape(n, -1)  # channel-major, as INRIA stores it
    cols += [(f"f_rest_{i}", rest[:, i]) for i in range(3 * (k - 1))]
    cols += [("opacity", g.opacity_logits)]
    cols += [(f"scale_{i}", g.log_scales[:, i]) for i in range(3)]
    cols += [(f"rot_{i}", g.quats[:, i]) for i in range(4)]
    rows = np.empty(n, dtype=[(name, "<f4") for name, _ in cols])
    for name, values in cols:
        rows[name] = values
    header = ["ply", "format binary_little_endian 1.0", *[f"comment {c}" for c in comments]]
    header += [f"element vertex {n}", *[f"property float {name}" for name, _ in cols], "end_header"]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(("\n".join(header) + "\n").encode() + rows.tobytes())


def write_sfm_points(path: Path, points: np.ndarray) -> None:
    """3DGS `storePly`: x y z nx ny nz (float) red green blue (uchar): the SfM points copied to input.ply."""
    rows = np.zeros(
        len(points),
        dtype=[(a, "<f4") for a in ("x", "y", "z", "nx", "ny", "nz")]
        + [(c, "u1") for c in ("red", "green", "blue")],
    )
    for i, a in enumerate("xyz"):
        rows[a] = points[:, i]
    rows["red"] = 200
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(points)}"]
    header += [f"property float {a}" for a in ("x", "y", "z", "nx", "ny", "nz")]
    header += [f"property uchar {c}" for c in ("red", "green", "blue")] + ["end_header"]
    path.write_bytes(("\n".join(header) + "\n").encode() + rows.tobytes())


def _copy_images(src: SourceScene, images_dir: Path) -> list[Frame]:
    """Images copied under their file names; frames renamed to them (COLMAP / 3DGS name images so)."""
    images_dir.mkdir(parents=True, exist_ok=True)
    out = []
    for f in src.frames:
        name = Path(f.image_path).name
        shutil.copy(f.image_path, images_dir / name)
        out.append(
            Frame(name, f.K.copy(), f.world_to_camera.copy(), f.width, f.height, image_path=images_dir / name)
        )
    return out


def inria_output(
    src: SourceScene, out: Path, data: Path, *, images: str = "images", resolution: int = -1
) -> Path:
    """`data` = the COLMAP dataset (images/, sparse/0), `out` = what `train.py -s data -m out` leaves."""
    frames = _copy_images(src, data / images)
    write_colmap_binary(data / "sparse" / "0", frames)
    out.mkdir(parents=True, exist_ok=True)
    (out / "cfg_args").write_text(
        f"Namespace(data_device='cuda', depths='', eval=False, images={images!r}, model_path={str(out)!r}, "
        f"resolution={resolution}, sh_degree={src.gaussians.sh_degree}, source_path={str(data.resolve())!r}, "
        "train_test_exp=False, white_background=False)"
    )
    write_cameras_json(out / "cameras.json", sorted(frames, key=lambda f: Path(f.name).stem))
    write_sfm_points(out / "input.ply", src.gaussians.means[::7])
    half = src.gaussians.subset(np.arange(0, len(src.gaussians), 2))  # an earlier, smaller iteration
    write_trainer_ply(out / "point_cloud" / "iteration_7000" / "point_cloud.ply", half, normals=True)
    write_trainer_ply(
        out / "point_cloud" / "iteration_30000" / "point_cloud.ply", src.gaussians, normals=True
    )
    return out


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation taking unit vector a to unit vector b (Rodrigues)."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    skew = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + skew + skew @ skew * (1.0 / (1.0 + c))


def nerfstudio_dataparser(c2w_opengl: np.ndarray) -> Similarity:
    """nerfstudio's `auto_orient_and_center_poses(method="up", center_method="poses")` then
    `auto_scale_poses`: rotate the mean camera up (+y of OpenGL c2w) to +z, centre on the mean
    camera position, scale so the largest |coordinate| of a camera position is 1."""
    origins = c2w_opengl[:, :3, 3]
    up = c2w_opengl[:, :3, 1].mean(axis=0)
    rot = _rotation_between(up, np.array([0.0, 0.0, 1.0]))
    orient = Similarity(1.0, rot, -rot @ origins.mean(axis=0))
    scale = 1.0 / float(np.abs(orient.points(origins)).max())
    return orient.then(Similarity(scale, np.eye(3), np.zeros(3)))


def _opengl_c2w(frames: list[Frame], world: Similarity | None = None) -> np.ndarray:
    c2w = invert_rigid(np.stack([f.world_to_camera for f in frames])) @ OPENGL_TO_OPENCV
    if world is not None:
        c2w = np.einsum("ij,njk->nik", world.matrix, c2w)
    return c2w


def splatfacto_output(src: SourceScene, out: Path, *, cameras: str = "transforms") -> Path:
    """ns-process-data's folder (images/, transforms.json with applied_transform, or COLMAP's
    sparse/0 for the colmap dataparser) plus the exported splat.ply and dataparser_transforms.json.

    transforms: the scene's world is transforms.json's frame; the dataset's original (COLMAP)
    frame is applied_transform^-1 of it. colmap: the scene's world is the COLMAP frame.
    """
    frames = _copy_images(src, out / "images")
    applied = Similarity.from_matrix(NS_PROCESS_DATA_APPLIED, source="applied")
    if cameras == "transforms":
        write_transforms(out / "transforms.json", frames)
        doc = json.loads((out / "transforms.json").read_text())
        doc["applied_transform"] = NS_PROCESS_DATA_APPLIED.tolist()
        (out / "transforms.json").write_text(json.dumps(doc, indent=4))
        saved_to_internal = nerfstudio_dataparser(_opengl_c2w(frames))
        original_to_internal = applied.then(saved_to_internal)
        world_to_internal = saved_to_internal
    else:
        write_colmap_binary(out / "sparse" / "0", frames)
        # colmap dataparser: the applied world change, then orientation/centring/scale on those poses.
        orient = nerfstudio_dataparser(_opengl_c2w(frames, applied))
        original_to_internal = applied.then(orient)
        world_to_internal = original_to_internal
    rigid = original_to_internal.then(Similarity(1.0 / original_to_internal.scale, np.eye(3), np.zeros(3)))
    (out / "dataparser_transforms.json").write_text(
        json.dumps({"transform": rigid.matrix[:3].tolist(), "scale": original_to_internal.scale}, indent=4)
    )
    write_trainer_ply(
        out / "splat.ply",
        world_to_internal.gaussians(src.gaussians),
        normals=True,
        comments=("Generated by Nerstudio 1.1.5", "Vertical Axis: z"),
    )
    return out


def gsplat_normalisation(frames: list[Frame], points: np.ndarray) -> Similarity:
    """gsplat `Parser(normalize=True).transform`: similarity_from_cameras (mean camera up (-y) to
    +z, centre on the median of the cameras' nearest points to the origin along their axes, scale
    by 1 / median camera distance), then PCA alignment of the points (about their median, largest
    variance first, proper rotation), then a 180-degree turn about x if median z > mean z."""
    c2w = invert_rigid(np.stack([f.world_to_camera for f in frames]))
    rot, t = c2w[:, :3, :3], c2w[:, :3, 3]
    up = (rot @ np.array([0.0, -1.0, 0.0])).mean(axis=0)
    align = _rotation_between(up, np.array([0.0, 0.0, 1.0]))
    fwd = (align @ rot @ np.array([0.0, 0.0, 1.0])[:, None])[..., 0]
    t_al = t @ align.T
    nearest = t_al + ((fwd * -t_al).sum(-1))[:, None] * fwd
    translate = -np.median(nearest, axis=0)
    scale = 1.0 / float(np.median(np.linalg.norm(t_al + translate, axis=-1)))
    t1 = Similarity(scale, align, scale * translate)
    pts = t1.points(points)
    centroid = np.median(pts, axis=0)
    vals, vecs = np.linalg.eigh(np.cov(pts - centroid, rowvar=False))
    vecs = vecs[:, vals.argsort()[::-1]]
    if np.linalg.det(vecs) < 0:
        vecs[:, 0] *= -1
    t2 = t1.then(Similarity(1.0, vecs.T, -vecs.T @ centroid))
    pts = t2.points(points)
    if np.median(pts[:, 2]) > np.mean(pts[:, 2]):
        t2 = t2.then(Similarity(1.0, np.diag([1.0, -1.0, -1.0]), np.zeros(3)))
    return t2


def gsplat_output(src: SourceScene, data: Path, *, step: int = 29999) -> Path:
    """The COLMAP dataset plus the trainer's `ply/point_cloud_<step>.ply` (normalised frame, no
    normals; an earlier step too) and the user's `splat_transform.json` with parser.transform."""
    frames = _copy_images(src, data / "images")
    write_colmap_binary(data / "sparse" / "0", frames)
    transform = gsplat_normalisation(frames, src.gaussians.means.astype(np.float64))
    normalised = transform.gaussians(src.gaussians)
    write_trainer_ply(data / "ply" / f"point_cloud_{step}.ply", normalised, normals=False)
    write_trainer_ply(data / "ply" / "point_cloud_6999.ply", normalised.subset(np.arange(10)), normals=False)
    (data / "splat_transform.json").write_text(json.dumps({"camera_to_splat": transform.matrix.tolist()}))
    return data


def scene_yaml_output(src: SourceScene, out: Path, splat_to_camera: Similarity) -> Path:
    """Anything else: the splat in its own frame under exports/, a COLMAP model under recon/0,
    images under photos/, and a scene.yaml naming them with the inline 4x4."""
    frames = _copy_images(src, out / "photos")
    write_colmap_binary(out / "recon" / "0", frames)
    write_trainer_ply(
        out / "exports" / "model.ply", splat_to_camera.inverse().gaussians(src.gaussians), normals=False
    )
    import yaml

    (out / "scene.yaml").write_text(
        yaml.safe_dump(
            {
                "splat": "exports/model.ply",
                "cameras": "recon/0",
                "images": "photos",
                "splat_to_camera": splat_to_camera.matrix.tolist(),
            }
        )
    )
    return out


def small_source_scene(root: Path, *, sh_degree: int, centre: tuple[float, float, float]) -> SourceScene:
    """300 random Gaussians around `centre`, 3 cameras looking at them, flat 64x48 images under
    `root / "src"`: the untransformed scene the layout tests (library and service) start from."""
    from tests.core.scene.conftest import look_at_frame, random_gaussians

    g = random_gaussians(300, sh_degree, extra=False)
    g.means[:] = g.means * 0.3 + np.array(centre, dtype=np.float32)
    frames = [
        look_at_frame("frame_00000.png", [2.0, 0.5, 1.5], 60.0, 60.0, 32.0, 24.0, 64, 48),
        look_at_frame("frame_00001.png", [-1.0, 2.0, 2.0], 60.0, 60.0, 32.0, 24.0, 64, 48),
        look_at_frame("frame_00002.png", [0.5, -2.5, 0.8], 60.0, 60.0, 32.0, 24.0, 64, 48),
    ]
    src = root / "src"
    src.mkdir()
    for i, f in enumerate(frames):
        f.image_path = src / f.name
        Image.new("RGB", (64, 48), (40 * i, 90, 200)).save(f.image_path)
    return SourceScene(g, frames)
