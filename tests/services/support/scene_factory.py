"""Small but real scenes for the service tests: a splat of coloured blobs on a floor, orbit
cameras, and images rendered from the splat itself (so perception sees the splat's objects).

Kept tiny (a few thousand Gaussians, 64x48 images) so an upload is a few hundred kB and a job
runs in seconds on a CPU.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
from PIL import Image

from bayesian_fields_core.geometry.spherical_harmonics import SH_C0
from bayesian_fields_core.render import render
from bayesian_fields_core.scene.nerfstudio import write_transforms
from bayesian_fields_core.scene.ply import write_ply
from bayesian_fields_core.scene.types import Frame, Gaussians


def blob_gaussians(n_per_blob: int = 400, seed: int = 0) -> Gaussians:
    """A floor plus four coloured blobs (red, green, blue, yellow) around the origin."""
    rng = np.random.default_rng(seed)
    colours = np.array([[0.9, 0.1, 0.1], [0.1, 0.8, 0.2], [0.1, 0.2, 0.9], [0.9, 0.9, 0.1]])
    centres = np.array([[0.5, 0.5, 0.15], [-0.5, 0.5, 0.15], [-0.5, -0.5, 0.15], [0.5, -0.5, 0.15]])
    means = [rng.normal(c, 0.08, size=(n_per_blob, 3)) for c in centres]
    rgb = [np.repeat(c[None], n_per_blob, 0) for c in colours]
    floor = np.c_[rng.uniform(-1.2, 1.2, size=(2 * n_per_blob, 2)), np.zeros(2 * n_per_blob)]
    means.append(floor)
    rgb.append(np.full((2 * n_per_blob, 3), 0.5))
    means_a = np.concatenate(means).astype(np.float32)
    rgb_a = np.concatenate(rgb)
    n = len(means_a)
    return Gaussians(
        means=means_a,
        log_scales=np.full((n, 3), np.log(0.03), np.float32),
        quats=np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
        opacity_logits=np.full(n, 3.0, np.float32),
        sh=((rgb_a - 0.5) / SH_C0).astype(np.float32)[:, None, :],
    )


def orbit_frames(count: int, width: int, height: int, radius: float = 2.5) -> list[Frame]:
    frames = []
    for i in range(count):
        angle = 2 * np.pi * i / count
        eye = np.array([radius * np.cos(angle), radius * np.sin(angle), 1.5])
        forward = -eye / np.linalg.norm(eye)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        rot = np.stack([right, down, forward])
        w2c = np.eye(4)
        w2c[:3, :3] = rot
        w2c[:3, 3] = -rot @ eye
        f = 0.9 * width
        K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])
        frames.append(Frame(f"frame_{i:03d}", K, w2c, width, height))
    return frames


def make_scene(folder: Path, *, frames: int = 4, width: int = 64, height: int = 48, seed: int = 0) -> Path:
    """Write splat.ply, transforms.json and images/*.png into `folder`; returns `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    gaussians = blob_gaussians(seed=seed)
    write_ply(folder / "splat.ply", gaussians)
    (folder / "images").mkdir(exist_ok=True)
    cams = orbit_frames(frames, width, height)
    for frame in cams:
        out = render(gaussians, frame.K, frame.world_to_camera, width, height, background=(0.2, 0.2, 0.2))
        rgb = (np.clip(out.rgb, 0, 1) * 255).astype(np.uint8)
        frame.image_path = folder / "images" / f"{frame.name}.png"
        Image.fromarray(rgb).save(frame.image_path)
    write_transforms(folder / "transforms.json", cams)
    return folder


def zip_bytes(entries: dict[str, bytes], *, symlinks: dict[str, str] | None = None) -> bytes:
    """A zip of `entries` (name -> content), plus symlink members (name -> target)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in entries.items():
            zf.writestr(name, data)
        for name, target in (symlinks or {}).items():
            info = zipfile.ZipInfo(name)
            info.external_attr = (0o120777 << 16) | 0
            zf.writestr(info, target)
    return buf.getvalue()


def image_zip(folder: Path) -> bytes:
    return zip_bytes({f"images/{p.name}": p.read_bytes() for p in sorted((folder / "images").iterdir())})
