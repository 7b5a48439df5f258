"""An INRIA 3DGS output folder (`train.py -m OUT`) as 3DGS writes it.

    OUT/cfg_args                               str(Namespace(source_path=..., images=..., resolution=...))
    OUT/cameras.json                           cameras (see `inria.py`)
    OUT/input.ply                              the SfM points 3DGS started from: NOT a splat
    OUT/point_cloud/iteration_<N>/point_cloud.ply   the trained splat at each saved iteration

The Gaussians and `cameras.json` share COLMAP's world frame (3DGS applies no normalisation to
either), so no transform is needed; what differs is where the images are and at what size.

- `cfg_args` is the `repr` of an argparse Namespace. 3DGS itself `eval`s it; we parse it with `ast`
  and accept only literal keyword values, so a hostile file can never run code.
- `cameras.json` widths/heights are those of the camera model 3DGS read; the images found may be
  the same size, an integer factor larger or smaller (3DGS `-r 1/2/4/8`: `round(W / r)`, or a
  pre-downscaled `images_<r>` folder), or 3DGS's automatic resize of images wider than 1600 px to
  1600 wide (`int(W / (W / 1600))`, height alike), or an explicit `-r <width>`. Then fx, fy and the
  (centred) principal point are rescaled to the image. Anything else is refused naming both sizes.
"""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

from PIL import Image

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.geometry.transforms import intrinsics
from bayesian_fields_core.scene.files import resolve_inside
from bayesian_fields_core.scene.types import Frame

CFG_ARGS = "cfg_args"
MAX_CFG_ARGS_BYTES = 64 * 1024
AUTO_RESIZE_WIDTH = 1600
"""3DGS `resolution=-1`: images wider than this are resized to this width (utils/camera_utils.py)."""
RESOLUTION_FACTORS = (1, 2, 4, 8)
"""3DGS `-r` values that mean a downscale factor rather than a target width."""


def read_cfg_args(path: str | Path) -> dict[str, Any]:
    """The keyword arguments of a 3DGS `cfg_args` file, parsed without evaluating anything."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", source=str(path)) from None
    if len(raw) > MAX_CFG_ARGS_BYTES:
        raise InputError(f"larger than {MAX_CFG_ARGS_BYTES} bytes; not a 3DGS cfg_args", source=str(path))
    try:
        tree = ast.parse(raw.decode("utf-8").strip(), mode="eval")
    except (UnicodeDecodeError, SyntaxError, ValueError) as exc:
        raise InputError(f"not a Namespace(...) expression ({exc})", source=str(path)) from None
    call = tree.body
    if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Name) and call.func.id == "Namespace"):
        raise InputError("expected Namespace(key=value, ...)", source=str(path))
    if call.args:
        raise InputError("Namespace(...) takes keyword arguments only", source=str(path))
    out: dict[str, Any] = {}
    for kw in call.keywords:
        if kw.arg is None:
            raise InputError("Namespace(**...) is not accepted", source=str(path))
        try:
            out[kw.arg] = ast.literal_eval(kw.value)
        except (ValueError, SyntaxError):
            raise InputError(f"value of {kw.arg!r} is not a literal", source=str(path)) from None
    return out


def _int_factor_size(width: int, height: int, factor: int) -> tuple[int, int]:
    return round(width / factor), round(height / factor)


def _width_resize(width: int, height: int, target: float) -> tuple[int, int]:
    """3DGS's resize to a target width: scale = W / target, size = int(W / scale), int(H / scale)."""
    scale = float(width / target)
    return int(width / scale), int(height / scale)


def _related(big: tuple[int, int], small: tuple[int, int]) -> bool:
    """Is `small` what 3DGS makes of `big` (an integer factor, or a resize to a width)?"""
    (bw, bh), (sw, sh) = big, small
    if sw <= 0 or sh <= 0:
        return False
    factor = max(1, round(bw / sw))
    if _int_factor_size(bw, bh, factor) == small or (bw == factor * sw and bh == factor * sh):
        return True
    return _width_resize(bw, bh, sw) == small


def rescale_to_images(frames: list[Frame], *, source: str) -> list[Frame]:
    """Frames whose K and size follow their image files when the sizes differ by 3DGS's rules.

    Reads each image header (not the pixels). A missing image is left to the caller's
    missing-file check. Raises InputError naming both sizes when they are unrelated.
    """
    out = []
    for frame in frames:
        path = frame.image_path
        if path is None or not Path(path).is_file():
            out.append(frame)
            continue
        try:
            with Image.open(path) as img:
                size = (img.width, img.height)
        except (OSError, ValueError) as exc:
            raise InputError(f"cannot read the image header ({exc})", source=str(path)) from None
        camera = (frame.width, frame.height)
        if size == camera:
            out.append(frame)
            continue
        bigger, smaller = (size, camera) if size[0] >= camera[0] else (camera, size)
        if not _related(bigger, smaller):
            raise InputError(
                f"image {Path(path).name} is {size[0]}x{size[1]} but its camera in cameras.json is "
                f"{camera[0]}x{camera[1]}: neither an integer factor nor 3DGS's resize to "
                f"{AUTO_RESIZE_WIDTH} px wide (is `images` in cfg_args the right folder?)",
                source=source,
            )
        sx, sy = size[0] / camera[0], size[1] / camera[1]
        K = frame.K
        out.append(
            Frame(
                name=frame.name,
                K=intrinsics(K[0, 0] * sx, K[1, 1] * sy, size[0] / 2.0, size[1] / 2.0),
                world_to_camera=frame.world_to_camera,
                width=size[0],
                height=size[1],
                image_path=frame.image_path,
                depth_path=frame.depth_path,
                depth_scale=frame.depth_scale,
                distortion=frame.distortion,
            )
        )
    return out


def is_inria_output(folder: Path) -> bool:
    """A 3DGS output folder: cameras.json plus point_cloud/iteration_<N>/ (or cfg_args)."""
    return (folder / "cameras.json").is_file() and (
        (folder / CFG_ARGS).is_file() or (folder / "point_cloud").is_dir()
    )


def inria_images(
    folder: Path, camera_path: Path, *, allow_source_path: bool
) -> tuple[Path | None, Path | None]:
    """(images_dir, root) for a cameras.json (`camera_formats` row 'inria', its `images`):
    `images/` beside it, else what cfg_args names.

    cfg_args' `images` (default 'images') is tried inside the scene folder first; its absolute
    `source_path` (where 3DGS read the dataset) is followed only with `allow_source_path` (the
    CLI), because an upload must never make the service open a host folder.
    """
    beside = camera_path.parent / "images"
    cfg = folder / CFG_ARGS
    if beside.is_dir() or not cfg.is_file():
        return None, None
    args = read_cfg_args(cfg)
    images = args.get("images") or "images"
    if not isinstance(images, str):
        raise InputError(f"images must be a string, got {images!r}", source=str(cfg))
    inside = resolve_inside(folder, images, what="images folder", source=str(cfg))
    if inside.is_dir():
        return inside, folder
    source = args.get("source_path")
    if not isinstance(source, str) or not source:
        return None, None
    source_dir = Path(source)
    if not source_dir.is_absolute():
        source_dir = folder / source_dir
    source_dir = source_dir.resolve()
    if not source_dir.is_relative_to(folder.resolve()) and not allow_source_path:
        raise InputError(
            f"the images are not in the scene folder and cfg_args names source_path {source!r} outside it; "
            f"copy {images}/ into the scene folder (the CLI may follow source_path, the service never does)",
            source=str(cfg),
        )
    return resolve_inside(source_dir, images, what="images folder", source=str(cfg)), source_dir
