"""Shared builders for the scene tests: random splats and look-at cameras with a known projection."""

from __future__ import annotations

import numpy as np
import pytest

from bayesian_fields_core.scene.types import Frame, Gaussians, sh_coefficient_count

TARGET = np.array([0.3, -0.2, 1.0])
"""A world point every test camera looks at, so it projects onto the principal point."""


def random_gaussians(n: int, degree: int, *, seed: int = 0, extra: bool = True) -> Gaussians:
    rng = np.random.default_rng(seed)
    k = sh_coefficient_count(degree)
    extras = {}
    if extra:
        extras = {
            "nx": rng.normal(size=n).astype(np.float32),
            "ny": rng.normal(size=n).astype(np.float32),
            "nz": rng.normal(size=n).astype(np.float32),
            "red": rng.integers(0, 256, size=n).astype(np.uint8),
            "confidence": rng.normal(size=n).astype(np.float64),
            "segment": rng.integers(-5, 5, size=n).astype(np.int32),
        }
    return Gaussians(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        log_scales=rng.normal(size=(n, 3)).astype(np.float32),
        quats=rng.normal(size=(n, 4)).astype(np.float32),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        sh=rng.normal(size=(n, k, 3)).astype(np.float32),
        extra=extras,
    )


def look_at_frame(
    name: str, eye, fx: float, fy: float, cx: float, cy: float, width: int, height: int
) -> Frame:
    """An OpenCV camera at `eye` whose optical axis passes through TARGET (world up = +z)."""
    eye = np.asarray(eye, dtype=np.float64)
    forward = (TARGET - eye) / np.linalg.norm(TARGET - eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    rot = np.stack([right, down, forward])  # rows: camera axes in world coordinates
    w2c = np.eye(4)
    w2c[:3, :3] = rot
    w2c[:3, 3] = -rot @ eye
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    return Frame(name, K, w2c, width, height)


def expected_pixel(frame: Frame, right_offset: float, down_offset: float) -> tuple[np.ndarray, np.ndarray]:
    """(world point, pixel) for TARGET moved along the camera's right/down axes, from first principles:
    at distance d, an offset a along x lands fx * a / d pixels right of the principal point."""
    rot = frame.world_to_camera[:3, :3]
    d = np.linalg.norm(TARGET - frame.camera_centre)
    point = TARGET + right_offset * rot[0] + down_offset * rot[1]
    pixel = np.array(
        [frame.K[0, 2] + frame.K[0, 0] * right_offset / d, frame.K[1, 2] + frame.K[1, 1] * down_offset / d]
    )
    return point, pixel


def project(frame: Frame, point: np.ndarray) -> np.ndarray:
    cam = frame.world_to_camera[:3, :3] @ point + frame.world_to_camera[:3, 3]
    assert cam[2] > 0
    uvw = frame.K @ cam
    return uvw[:2] / uvw[2]


@pytest.fixture
def frames() -> list[Frame]:
    """Three cameras with distinct poses and intrinsics (non-square pixels, off-centre principal points)."""
    return [
        look_at_frame("frame_2.png", [3.0, 0.5, 1.5], 500.0, 510.0, 320.0, 240.0, 640, 480),
        look_at_frame("frame_10.png", [-1.0, 2.5, 2.0], 420.0, 415.0, 330.5, 250.25, 640, 480),
        look_at_frame("frame_1.png", [0.5, -3.0, 0.5], 300.0, 300.0, 160.0, 120.0, 320, 240),
    ]
