"""COLMAP sparse models (`cameras` + `images`, text or binary) <-> Frames.

COLMAP stores each image's pose as the world-to-camera rotation quaternion (qw, qx, qy, qz) and
translation, already in the OpenCV axes, so a pose maps straight to `Frame.world_to_camera`.
Pinhole models become K; SIMPLE_RADIAL / RADIAL / OPENCV keep their coefficients in
`Frame.distortion` for `images.load_image` to remove; fisheye and other models are refused by name
because silently treating them as pinhole would misplace every mask. `points3D` is read only for gsplat's
world normalisation. COLMAP 3.12's `frames.*` and `rigs.*` are ignored: `images.*` still carries
every image's pose.

Frames come back sorted by image name (natural order: "img2" before "img10"), COLMAP's image ids
being registration order rather than capture order, unless the caller gives an explicit order.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bayesian_fields_core.errors import InputError, input_boundary
from bayesian_fields_core.geometry.transforms import intrinsics, quat_to_rotmat, rigid, rotmat_to_quat
from bayesian_fields_core.scene.images import clean_distortion, resolve_image_path
from bayesian_fields_core.scene.types import Frame

# COLMAP model id -> (name, parameter count); the full list, so unsupported ones are named in errors.
MODELS: dict[int, tuple[str, int]] = {
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
}
MODEL_IDS = {name: mid for mid, (name, _) in MODELS.items()}
SUPPORTED_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")

# One camera: (model name, width, height, params); one image: (qvec, tvec, camera id, name).
_Camera = tuple[str, int, int, list[float]]
_Image = tuple[list[float], list[float], int, str]


def natural_key(name: str) -> list:
    """Sort key that orders embedded numbers numerically ("img2" < "img10")."""
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def _camera_intrinsics(
    model: str, params: list[float], source: str, camera_id: int
) -> tuple[np.ndarray, dict[str, float] | None]:
    """(K, distortion | None) for a supported model; InputError naming anything else."""
    if model not in SUPPORTED_MODELS:
        raise InputError(
            f"camera {camera_id} uses the unsupported camera model {model} "
            f"(supported: {', '.join(SUPPORTED_MODELS)})",
            source=source,
        )
    if model == "SIMPLE_PINHOLE":
        f, cx, cy = params
        return intrinsics(f, f, cx, cy), None
    if model == "PINHOLE":
        return intrinsics(*params), None
    if model == "SIMPLE_RADIAL":
        f, cx, cy, k1 = params
        dist = {"k1": k1}
    elif model == "RADIAL":
        f, cx, cy, k1, k2 = params
        dist = {"k1": k1, "k2": k2}
    else:  # OPENCV
        fx, fy, cx, cy, k1, k2, p1, p2 = params
        return intrinsics(fx, fy, cx, cy), clean_distortion(
            {"k1": k1, "k2": k2, "p1": p1, "p2": p2}, source=f"{source} camera {camera_id}"
        )
    return intrinsics(f, f, cx, cy), clean_distortion(dist, source=f"{source} camera {camera_id}")


def _data_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, stripped line) for every line of a text model file."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read COLMAP file ({exc})", source=str(path)) from exc
    return list(enumerate((line.strip() for line in text.splitlines()), start=1))


def _read_cameras_text(path: Path) -> dict[int, _Camera]:
    cameras: dict[int, _Camera] = {}
    for lineno, line in _data_lines(path):
        if not line or line.startswith("#"):
            continue
        tokens = line.split()
        where = f"{path}:{lineno}"
        try:
            cam_id, model, width, height = int(tokens[0]), tokens[1], int(tokens[2]), int(tokens[3])
            params = [float(t) for t in tokens[4:]]
        except (IndexError, ValueError) as exc:
            raise InputError(
                f"bad camera line {line!r} (expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS...)", source=where
            ) from exc
        if model not in MODEL_IDS:
            raise InputError(f"camera {cam_id}: unknown camera model {model}", source=where)
        if len(params) != MODELS[MODEL_IDS[model]][1]:
            raise InputError(
                f"camera {cam_id}: model {model} takes {MODELS[MODEL_IDS[model]][1]} parameters, got {len(params)}",
                source=where,
            )
        cameras[cam_id] = (model, width, height, params)
    return cameras


def _read_images_text(path: Path) -> list[_Image]:
    """Image lines; each is followed by a POINTS2D line (possibly empty) that we skip."""
    images: list[_Image] = []
    lines = _data_lines(path)
    i = 0
    while i < len(lines):
        lineno, line = lines[i]
        i += 1
        if not line or line.startswith("#"):
            continue
        tokens = line.split(maxsplit=9)
        try:
            if len(tokens) != 10:
                raise ValueError
            values = [float(t) for t in tokens[1:8]]
            cam_id = int(tokens[8])
        except ValueError as exc:
            raise InputError(
                f"bad image line {line!r} (expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME)",
                source=f"{path}:{lineno}",
            ) from exc
        images.append((values[:4], values[4:], cam_id, tokens[9]))
        i += 1  # the POINTS2D line
    return images


class _Reader:
    """Bounds-checked little-endian reads from a COLMAP binary file."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self.data = path.read_bytes()
        except OSError as exc:
            raise InputError(f"cannot read COLMAP file ({exc.strerror})", source=str(path)) from exc
        self.pos = 0

    def take(self, fmt: str, what: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise InputError(f"truncated while reading {what} at byte {self.pos}", source=str(self.path))
        values = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return values

    def cstring(self, what: str) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise InputError(f"truncated while reading {what} at byte {self.pos}", source=str(self.path))
        raw, self.pos = self.data[self.pos : end], end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise InputError(f"{what} is not valid UTF-8", source=str(self.path)) from exc

    def skip(self, nbytes: int, what: str) -> None:
        if self.pos + nbytes > len(self.data):
            raise InputError(f"truncated while reading {what} at byte {self.pos}", source=str(self.path))
        self.pos += nbytes


def _read_cameras_binary(path: Path) -> dict[int, _Camera]:
    r = _Reader(path)
    (count,) = r.take("Q", "the camera count")
    cameras: dict[int, _Camera] = {}
    for i in range(count):
        cam_id, model_id, width, height = r.take("iiQQ", f"camera #{i}")
        if model_id not in MODELS:
            raise InputError(f"camera {cam_id}: unknown camera model id {model_id}", source=str(path))
        name, nparams = MODELS[model_id]
        params = list(r.take("d" * nparams, f"camera {cam_id} parameters"))
        cameras[cam_id] = (name, width, height, params)
    return cameras


def _read_images_binary(path: Path) -> list[_Image]:
    r = _Reader(path)
    (count,) = r.take("Q", "the image count")
    images: list[_Image] = []
    for i in range(count):
        values = r.take("i7di", f"image #{i}")
        name = r.cstring(f"image #{i} name")
        (npoints,) = r.take("Q", f"image {name} point count")
        r.skip(24 * npoints, f"image {name} points")  # (x, y, point3D_id) per point
        images.append((list(values[1:5]), list(values[5:8]), values[8], name))
    return images


def _model_files(sparse_dir: Path) -> tuple[Path, Path, bool]:
    """(cameras, images, binary): binary files win when both kinds exist, like COLMAP itself."""
    for ext, binary in ((".bin", True), (".txt", False)):
        cams, imgs = sparse_dir / f"cameras{ext}", sparse_dir / f"images{ext}"
        if cams.is_file() and imgs.is_file():
            return cams, imgs, binary
    raise InputError(
        "no COLMAP model (cameras.bin + images.bin or cameras.txt + images.txt)", source=str(sparse_dir)
    )


def images_file(sparse_dir: Path) -> Path:
    """The file of a COLMAP model that lists its images (`images.bin`, else `images.txt`): where a
    frame is dropped from the model."""
    return _model_files(sparse_dir)[1]


def _default_images_dir(sparse_dir: Path) -> Path:
    """`<scene>/images` for the usual `<scene>/sparse/0` or `<scene>/sparse` layouts, and for
    ns-process-data's `<scene>/colmap/sparse/0`."""
    candidates = [sparse_dir.parent / "images", sparse_dir.parent.parent / "images"]
    if sparse_dir.parent.parent.name == "colmap":
        candidates.append(sparse_dir.parent.parent.parent / "images")
    for candidate in candidates:
        if candidate.is_dir():
            return candidate
    return sparse_dir.parent / "images"


def read_colmap(
    sparse_dir: str | Path,
    images_dir: str | Path | None = None,
    *,
    order: Sequence[str] | None = None,
) -> list[Frame]:
    """Frames of a COLMAP sparse model, sorted by image name (or exactly `order`, by image name).

    `images_dir` defaults to the `images/` folder beside `sparse/` (image names are relative to it
    and must stay inside it, `resolve_inside`). Any parse failure is an InputError.
    """
    sparse_dir = Path(sparse_dir)
    with input_boundary(str(sparse_dir), what="cannot read the COLMAP model"):
        return _read_colmap(sparse_dir, images_dir, order)


def _read_colmap(sparse_dir: Path, images_dir: str | Path | None, order: Sequence[str] | None) -> list[Frame]:
    cams_path, imgs_path, binary = _model_files(sparse_dir)
    cameras = _read_cameras_binary(cams_path) if binary else _read_cameras_text(cams_path)
    images = _read_images_binary(imgs_path) if binary else _read_images_text(imgs_path)
    if not images:
        raise InputError("the COLMAP model has no images", source=str(imgs_path))
    root = Path(images_dir) if images_dir is not None else _default_images_dir(sparse_dir)

    by_name = {img[3]: img for img in images}
    if order is None:
        names = sorted(by_name, key=natural_key)
    else:
        unknown = [n for n in order if n not in by_name]
        if unknown:
            raise InputError(
                f"images not in the COLMAP model: {', '.join(unknown[:5])}", source=str(imgs_path)
            )
        names = list(order)

    qvecs = np.array([by_name[n][0] for n in names], dtype=np.float64)
    tvecs = np.array([by_name[n][1] for n in names], dtype=np.float64)
    if (
        not (np.isfinite(qvecs).all() and np.isfinite(tvecs).all())
        or (np.linalg.norm(qvecs, axis=1) < 1e-12).any()
    ):
        raise InputError("non-finite or zero-length pose quaternion/translation", source=str(imgs_path))
    poses = rigid(quat_to_rotmat(qvecs), tvecs)

    frames = []
    for name, pose in zip(names, poses, strict=True):
        cam_id = by_name[name][2]
        if cam_id not in cameras:
            raise InputError(
                f"image {name} refers to camera {cam_id}, which {cams_path.name} lacks", source=str(imgs_path)
            )
        model, width, height, params = cameras[cam_id]
        K, dist = _camera_intrinsics(model, params, str(cams_path), cam_id)
        if width <= 0 or height <= 0 or not (np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0):
            raise InputError(
                f"camera {cam_id}: invalid size {width}x{height} or focal length", source=str(cams_path)
            )
        image_path = resolve_image_path(root, name, source=str(imgs_path))  # containment first
        frames.append(Frame(name, K, pose, int(width), int(height), image_path=image_path, distortion=dist))
    return frames


# ---------------------------------------------------------------------------------------------
# Writers: used by the synthetic scene generator and the tests.


def _camera_record(frame: Frame) -> tuple[str, list[float]]:
    """(model, params): the simplest COLMAP model that holds the frame's K and distortion."""
    K = frame.K
    if abs(K[0, 1]) > 1e-12:
        raise InputError("COLMAP cameras cannot express a skewed K", source=frame.name)
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    d = {k: float(v) for k, v in (frame.distortion or {}).items() if v != 0.0}
    if not d:
        return "PINHOLE", [fx, fy, cx, cy]
    if "k3" in d:
        raise InputError("COLMAP's supported models have no k3 coefficient", source=frame.name)
    if fx == fy and set(d) == {"k1"}:
        return "SIMPLE_RADIAL", [fx, cx, cy, d["k1"]]
    if fx == fy and set(d) <= {"k1", "k2"}:
        return "RADIAL", [fx, cx, cy, d.get("k1", 0.0), d["k2"]]
    return "OPENCV", [fx, fy, cx, cy] + [d.get(k, 0.0) for k in ("k1", "k2", "p1", "p2")]


def _records(
    frames: Sequence[Frame],
) -> tuple[list[tuple[int, str, int, int, tuple[float, ...]]], list[tuple[np.ndarray, np.ndarray, int, str]]]:
    """Shared cameras (identical intrinsics share an id) and per-image (qvec, tvec, cam id, name)."""
    camera_ids: dict[tuple, int] = {}
    images = []
    quats = rotmat_to_quat(np.stack([f.world_to_camera[:3, :3] for f in frames]))
    for frame, q in zip(frames, quats, strict=True):
        model, params = _camera_record(frame)
        key = (model, frame.width, frame.height, tuple(params))
        cam_id = camera_ids.setdefault(key, len(camera_ids) + 1)
        images.append((q, frame.world_to_camera[:3, 3], cam_id, frame.name))
    cameras = [(cid, model, w, h, params) for (model, w, h, params), cid in camera_ids.items()]
    return cameras, images


def write_colmap_text(sparse_dir: str | Path, frames: Sequence[Frame]) -> None:
    """Write `cameras.txt`, `images.txt` and an empty `points3D.txt` (full float64 precision)."""
    sparse_dir = Path(sparse_dir)
    sparse_dir.mkdir(parents=True, exist_ok=True)
    cameras, images = _records(frames)
    num = "{:.17g}".format
    cam_lines = [
        "# Camera list with one line of data per camera:",
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
    ]
    cam_lines += [
        f"{cid} {model} {w} {h} " + " ".join(map(num, params)) for cid, model, w, h, params in cameras
    ]
    img_lines = [
        "# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "# POINTS2D[] as (X, Y, POINT3D_ID)",
    ]
    for i, (q, t, cid, name) in enumerate(images, start=1):
        img_lines += [f"{i} " + " ".join(map(num, [*q, *t])) + f" {cid} {name}", ""]
    (sparse_dir / "cameras.txt").write_text("\n".join(cam_lines) + "\n")
    (sparse_dir / "images.txt").write_text("\n".join(img_lines) + "\n")
    (sparse_dir / "points3D.txt").write_text("# 3D point list (empty)\n")


def write_colmap_binary(sparse_dir: str | Path, frames: Sequence[Frame]) -> None:
    """Write `cameras.bin`, `images.bin` and an empty `points3D.bin` in COLMAP's binary layout."""
    sparse_dir = Path(sparse_dir)
    sparse_dir.mkdir(parents=True, exist_ok=True)
    cameras, images = _records(frames)
    cam_blob = struct.pack("<Q", len(cameras)) + b"".join(
        struct.pack(f"<iiQQ{len(params)}d", cid, MODEL_IDS[model], w, h, *params)
        for cid, model, w, h, params in cameras
    )
    img_blob = struct.pack("<Q", len(images)) + b"".join(
        struct.pack("<i7di", i, *q, *t, cid) + name.encode("utf-8") + b"\0" + struct.pack("<Q", 0)
        for i, (q, t, cid, name) in enumerate(images, start=1)
    )
    (sparse_dir / "cameras.bin").write_bytes(cam_blob)
    (sparse_dir / "images.bin").write_bytes(img_blob)
    (sparse_dir / "points3D.bin").write_bytes(struct.pack("<Q", 0))


def read_colmap_points(sparse_dir: str | Path) -> np.ndarray:
    """(N, 3) float64 positions of a COLMAP model's 3D points (points3D.bin, else .txt), or an
    empty array when the model has none. gsplat's world normalisation aligns on them."""
    sparse_dir = Path(sparse_dir)
    with input_boundary(str(sparse_dir), what="cannot read the COLMAP points"):
        binary, text = sparse_dir / "points3D.bin", sparse_dir / "points3D.txt"
        if binary.is_file():
            reader = _Reader(binary)
            (count,) = reader.take("Q", "point count")
            points = np.empty((count, 3), np.float64) if count * 43 <= len(reader.data) else None
            if points is None:
                raise InputError(f"{count} points cannot fit in the file", source=str(binary))
            for i in range(count):
                values = reader.take("Q3d3BdQ", "point")
                points[i] = values[1:4]
                reader.skip(8 * values[-1], "point track")
            return points
        if text.is_file():
            rows = [line.split() for _, line in _data_lines(text) if line and not line.startswith("#")]
            return np.array([[float(v) for v in row[1:4]] for row in rows], dtype=np.float64).reshape(-1, 3)
    return np.zeros((0, 3), np.float64)
