"""Image and depth loading: undistortion geometry, colour modes, size checks and depth units."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.geometry.transforms import intrinsics
from bayesian_fields_core.scene.images import (
    check_image,
    distort_normalized,
    load_depth,
    load_image,
    undistort_image,
)
from bayesian_fields_core.scene.types import Frame

W, H = 320, 240
K = intrinsics(200.0, 210.0, 161.0, 118.5)
DISTORTION = {"k1": -0.25, "k2": 0.05, "p1": 0.002, "p2": -0.003}


def frame(path=None, *, width=W, height=H, distortion=None, depth=None, depth_scale=1.0) -> Frame:
    return Frame(
        "f",
        K,
        np.eye(4),
        width,
        height,
        image_path=path,
        depth_path=depth,
        depth_scale=depth_scale,
        distortion=distortion,
    )


def grid_points() -> tuple[np.ndarray, np.ndarray]:
    """Pinhole pixels of a 5x4 grid spread to near the corners, and where the lens moves them."""
    u, v = np.meshgrid(np.linspace(25, W - 25, 5), np.linspace(25, H - 25, 4))
    pinhole = np.stack([u.ravel(), v.ravel()], axis=1)
    xd, yd = distort_normalized(
        (pinhole[:, 0] - K[0, 2]) / K[0, 0], (pinhole[:, 1] - K[1, 2]) / K[1, 1], DISTORTION
    )
    return pinhole, np.stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=1)


def blob_image(centres: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    """A grid of Gaussian dots drawn at continuous pixel positions (pixel centres at i + 0.5)."""
    v, u = np.mgrid[0:H, 0:W] + 0.5
    d2 = (u[None] - centres[:, 0, None, None]) ** 2 + (v[None] - centres[:, 1, None, None]) ** 2
    img = 255.0 * np.exp(-d2 / (2 * sigma**2)).max(axis=0)
    return np.repeat(np.rint(img).astype(np.uint8)[..., None], 3, axis=2)


def centroids(image: np.ndarray, guesses: np.ndarray, radius: int = 7) -> np.ndarray:
    """Intensity-weighted centre of the dot near each guess (continuous pixel coordinates)."""
    out = []
    for gu, gv in guesses:
        i0, j0 = int(gv) - radius, int(gu) - radius
        patch = image[i0 : i0 + 2 * radius + 1, j0 : j0 + 2 * radius + 1, 0].astype(np.float64)
        v, u = np.mgrid[i0 : i0 + patch.shape[0], j0 : j0 + patch.shape[1]] + 0.5
        out.append([(patch * u).sum() / patch.sum(), (patch * v).sum() / patch.sum()])
    return np.array(out)


def test_undistortion_moves_known_points_to_their_pinhole_pixels(tmp_path):
    pinhole, distorted = grid_points()
    shift = np.linalg.norm(distorted - pinhole, axis=1)
    assert shift.max() > 15  # the lens moves the corner dots far: the test would notice a no-op
    captured = blob_image(distorted)
    np.testing.assert_allclose(centroids(captured, distorted), distorted, atol=0.05)  # dots are where drawn

    Image.fromarray(captured).save(tmp_path / "d.png")
    fixed = load_image(frame(tmp_path / "d.png", distortion=DISTORTION))
    assert fixed.shape == (H, W, 3) and fixed.dtype == np.uint8
    error = np.linalg.norm(centroids(fixed, pinhole) - pinhole, axis=1)
    assert error.max() < 0.25, error  # a half-pixel centre-convention slip shows up as ~0.5
    np.testing.assert_array_equal(fixed, undistort_image(captured, K, DISTORTION))


def test_pinhole_frames_are_returned_unchanged_and_rgba_drops_alpha(tmp_path):
    rng = np.random.default_rng(0)
    rgba = rng.integers(0, 256, size=(H, W, 4), dtype=np.uint8)
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    np.testing.assert_array_equal(load_image(frame(tmp_path / "a.png")), rgba[..., :3])
    grey = rng.integers(0, 256, size=(H, W), dtype=np.uint8)
    Image.fromarray(grey, "L").save(tmp_path / "g.png")
    np.testing.assert_array_equal(
        load_image(frame(tmp_path / "g.png")), np.repeat(grey[..., None], 3, axis=2)
    )


def test_wrong_image_size_names_file_and_both_sizes(tmp_path):
    Image.new("RGB", (W // 2, H // 2)).save(tmp_path / "small.jpg")
    for loader in (load_image, check_image):
        with pytest.raises(InputError) as info:
            loader(frame(tmp_path / "small.jpg"))
        message = str(info.value)
        assert (
            str(tmp_path / "small.jpg") in message
            and f"is {W // 2}x{H // 2}" in message
            and f"is {W}x{H}" in message
        )


def test_missing_and_corrupt_images(tmp_path):
    with pytest.raises(InputError, match="image not found"):
        load_image(frame(tmp_path / "none.png"))
    Image.new("RGB", (W, H)).save(tmp_path / "c.png")
    (tmp_path / "c.png").write_bytes((tmp_path / "c.png").read_bytes()[:60])
    with pytest.raises(InputError, match=r"c\.png: cannot decode image"):
        load_image(frame(tmp_path / "c.png"))


def test_depth_png_and_npy_in_metres(tmp_path):
    assert load_depth(frame()) is None
    raw = np.arange(H * W, dtype=np.uint16).reshape(H, W)
    Image.fromarray(raw).save(tmp_path / "d.png")
    depth = load_depth(frame(depth=tmp_path / "d.png", depth_scale=0.001))
    assert depth.dtype == np.float32 and depth.shape == (H, W)
    np.testing.assert_allclose(depth, raw.astype(np.float32) * np.float32(0.001))
    metres = np.full((H, W), 2.5, np.float32)
    metres[0, 0] = np.nan
    np.save(tmp_path / "d.npy", metres)
    depth = load_depth(frame(depth=tmp_path / "d.npy"))
    assert depth[0, 0] == 0.0 and depth[1, 1] == 2.5


def test_bad_depth_inputs(tmp_path):
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match=r"obj\.npy: cannot read depth array"):
        load_depth(frame(depth=tmp_path / "obj.npy"))
    np.save(tmp_path / "small.npy", np.zeros((H, W - 1), np.float32))
    with pytest.raises(InputError, match=f"depth map is {W - 1}x{H}"):
        load_depth(frame(depth=tmp_path / "small.npy"))
    Image.new("L", (W, H)).save(tmp_path / "eight.png")
    with pytest.raises(InputError, match="mode 'L' is not 16/32-bit"):
        load_depth(frame(depth=tmp_path / "eight.png"))
