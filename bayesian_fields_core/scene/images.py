"""Load a frame's image (undistorted to its pinhole K) and optional depth map.

Camera readers keep a distorted camera's coefficients in `Frame.distortion` instead of refusing
it, so the image must be undistorted here before anything downstream (which assumes a pinhole
camera) sees it. We resample rather than adjusting K: every output pixel is pushed through the
distortion model (OpenCV/COLMAP polynomial: k1, k2, k3 radial; p1, p2 tangential) to find where
it lies in the captured image, then sampled bilinearly. The output keeps the frame's K and size,
so the pinhole camera stays the one the splat was trained with.

Pixel convention (COLMAP's, whose distortion coefficients these are): pixel (i, j) covers
[i, i+1) x [j, j+1), so its centre is at continuous coordinate (i + 0.5, j + 0.5).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image
from scipy import ndimage

from bayesian_fields_core.errors import InputError, describe_failure
from bayesian_fields_core.scene.files import resolve_inside
from bayesian_fields_core.scene.types import Frame

DISTORTION_KEYS = ("k1", "k2", "k3", "p1", "p2")
"""Coefficients of the polynomial distortion model this loader can remove (missing ones are 0)."""

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG")
"""Tried, in order, when a camera file names an image without its extension (INRIA, Blender)."""

DEPTH_PNG_MODES = ("I;16", "I;16B", "I;16L", "I", "F")
"""PIL modes accepted for depth images: 16-bit integer, 32-bit integer or float."""

PIXEL_CENTRE_OFFSET = 0.5
"""Continuous coordinate of the first pixel's centre (see the module docstring)."""


def clean_distortion(params: dict[str, float], *, source: str) -> dict[str, float] | None:
    """Validated distortion coefficients, or None when they are all zero (a pinhole camera)."""
    unknown = sorted(set(params) - set(DISTORTION_KEYS))
    if unknown:
        raise InputError(f"unsupported distortion coefficients {unknown}", source=source)
    values = {k: float(v) for k, v in params.items()}
    bad = [k for k, v in values.items() if not np.isfinite(v)]
    if bad:
        raise InputError(f"non-finite distortion coefficients {bad}", source=source)
    return values if any(v != 0.0 for v in values.values()) else None


def resolve_image_path(images_dir: Path, name: str, *, source: str = "cameras") -> Path:
    """`images_dir / name`, or with the first extension of IMAGE_EXTENSIONS that exists.

    Every candidate is checked by `resolve_inside` first (it must stay inside `images_dir` once
    symlinks are resolved), so a camera file cannot make us probe host files. Returns the plain
    (resolved) path when nothing exists, so the caller's "missing image" error names it.
    """
    path = resolve_inside(images_dir, name, what="image", source=source)
    if path.is_file():
        return path
    for ext in IMAGE_EXTENSIONS:
        candidate = resolve_inside(images_dir, name + ext, what="image", source=source)
        if candidate.is_file():
            return candidate
    return path


def distort_normalized(
    x: np.ndarray, y: np.ndarray, distortion: dict[str, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Apply the OpenCV/COLMAP polynomial distortion to normalized image coordinates."""
    k1, k2, k3, p1, p2 = (float(distortion.get(k, 0.0)) for k in DISTORTION_KEYS)
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return xd, yd


def undistort_image(image: np.ndarray, K: np.ndarray, distortion: dict[str, float]) -> np.ndarray:
    """Resample a distorted (H, W, C) image into the pinhole camera K of the same size.

    Output pixels whose source falls outside the captured image are black.
    """
    h, w = image.shape[:2]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    v, u = np.mgrid[0:h, 0:w].astype(np.float64) + PIXEL_CENTRE_OFFSET
    xd, yd = distort_normalized((u - cx) / fx, (v - cy) / fy, distortion)
    rows = fy * yd + cy - PIXEL_CENTRE_OFFSET
    cols = fx * xd + cx - PIXEL_CENTRE_OFFSET
    src = image.astype(np.float32)
    out = np.stack(
        [
            ndimage.map_coordinates(src[..., c], [rows, cols], order=1, mode="constant", cval=0.0)
            for c in range(src.shape[2])
        ],
        axis=-1,
    )
    if image.dtype == np.uint8:
        return np.clip(np.rint(out), 0, 255).astype(np.uint8)
    return out.astype(image.dtype)


def _open(path: Path, what: str) -> Image.Image:
    """A fully decoded PIL image, or an InputError naming the file."""
    try:
        img = Image.open(path)
        img.load()
    except FileNotFoundError as exc:
        raise InputError(f"{what} not found", source=str(path)) from exc
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError, MemoryError, EOFError) as exc:
        raise InputError(f"cannot decode {what} ({describe_failure(exc)})", source=str(path)) from exc
    return img


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) from the image's header, nothing decoded: the cheap size check a run does
    on every frame before any expensive work (the full decode comes with perception)."""
    try:
        with Image.open(path) as img:
            return img.size
    except FileNotFoundError as exc:
        raise InputError("image not found", source=str(path)) from exc
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError, MemoryError, EOFError) as exc:
        raise InputError(f"cannot read image ({describe_failure(exc)})", source=str(path)) from exc


def _check_size(path: Path, frame: Frame, width: int, height: int, what: str) -> None:
    if (width, height) != (frame.width, frame.height):
        raise InputError(
            f"{what} is {width}x{height} but its camera ({frame.name}) is {frame.width}x{frame.height}",
            source=str(path),
        )


def _image_path(frame: Frame) -> Path:
    if frame.image_path is None:
        raise InputError("frame has no image path", source=frame.name)
    return Path(frame.image_path)


def check_image(frame: Frame) -> None:
    """Decode the frame's image and check its size against the camera (no undistortion)."""
    path = _image_path(frame)
    img = _open(path, "image")
    _check_size(path, frame, img.width, img.height, "image")


def load_image(frame: Frame) -> np.ndarray:
    """The frame's image as (H, W, 3) uint8 RGB in its pinhole camera.

    Alpha is dropped (RGBA -> RGB); grey and palette images are expanded to RGB.
    """
    path = _image_path(frame)
    img = _open(path, "image")
    _check_size(path, frame, img.width, img.height, "image")
    rgb = np.asarray(img.convert("RGB"), dtype=np.uint8)
    if frame.distortion:
        rgb = undistort_image(rgb, frame.K, frame.distortion)
    return rgb


def load_depth(frame: Frame) -> np.ndarray | None:
    """The frame's depth map in metres as (H, W) float32, or None when the frame has none.

    A 16-bit (or 32-bit / float) PNG or TIFF, or a `.npy` array, times `frame.depth_scale`.
    Invalid samples (NaN, inf, negative) become 0, the "no depth" value the renderer also uses.
    Depth is not undistorted: depth inputs come from pinhole sensors or renders in practice.
    """
    if frame.depth_path is None:
        return None
    path = Path(frame.depth_path)
    if path.suffix.lower() == ".npy":
        try:
            raw = np.load(path, allow_pickle=False)
        except FileNotFoundError as exc:
            raise InputError("depth file not found", source=str(path)) from exc
        except (OSError, ValueError, MemoryError, EOFError) as exc:
            raise InputError(f"cannot read depth array ({describe_failure(exc)})", source=str(path)) from exc
        if raw.ndim == 3 and raw.shape[2] == 1:
            raw = raw[..., 0]
        if raw.ndim != 2 or raw.dtype.kind not in "uif":
            raise InputError(
                f"depth array must be (H, W) numeric, got {raw.dtype}{raw.shape}", source=str(path)
            )
    else:
        img = _open(path, "depth image")
        if img.mode not in DEPTH_PNG_MODES:
            raise InputError(
                f"depth image mode {img.mode!r} is not 16/32-bit or float (accepted: {', '.join(DEPTH_PNG_MODES)})",
                source=str(path),
            )
        raw = np.asarray(img)
    _check_size(path, frame, raw.shape[1], raw.shape[0], "depth map")
    depth = raw.astype(np.float32) * np.float32(frame.depth_scale)
    depth[~np.isfinite(depth) | (depth < 0)] = 0.0  # 0 = no measurement, as in rendered depth
    return depth
