"""Where the viewer starts and where its box labels go: plain geometry, testable without a browser.

Start: at the first training camera, as it saw the scene (its centre, its optical axis, its up =
-y in OpenCV, its vertical field of view). viser's own default (a 75 degree view from (3, 3, 3)
towards the origin, or the first camera's centre looking at the mean of all Gaussians) showed the
sample small and askew: the mean of a splat's Gaussians is pulled by floaters, and 75 degrees is
far wider than a capture's lens. The orbit pivot (`look_at`) is the point on the optical axis at
the median depth of the Gaussians the camera sees, so orbiting turns around what is in view.

Labels: one per selected object, short ("#rank p"; the panel's legend names the object), anchored
at the top of its box and stacked so that, seen from the start camera, no two overlap: in rank
order each label is raised along the camera's up axis until its screen rectangle clears those
already placed. Labels are HTML of a fixed pixel size, so no placement keeps them apart at every
zoom; the start view is the one every user sees, and stacking in world space keeps labels in
their box's column as the view turns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayesian_fields_core.scene.types import Frame

LABEL_HEIGHT = 0.035
"""A label's height as a share of the view's height: viser's labels are about 20 px high (a
chromium screenshot at 1280x800), kept apart in a view as small as 600 px."""
LABEL_CHAR_WIDTH = 0.012
"""Width of one character of a label as a share of the view's height (about 6.5 px)."""
LABEL_GAP = 0.005
"""Space left between stacked labels, as a share of the view's height."""


@dataclass(frozen=True)
class StartView:
    """The viewer's initial camera in world coordinates; `fov` is vertical, in radians."""

    position: tuple[float, float, float]
    look_at: tuple[float, float, float]
    up: tuple[float, float, float]
    fov: float


def _xyz(v: np.ndarray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def start_view(frame: Frame, points: np.ndarray) -> StartView:
    """The view of `frame` (see the module docstring); `points` (N, 3) are the Gaussians' means,
    whose median depth in front of the camera sets the orbit pivot (1 unit ahead if none is)."""
    c2w = np.asarray(frame.camera_to_world, dtype=np.float64)
    centre, forward, up = c2w[:3, 3], c2w[:3, 2], -c2w[:3, 1]
    w2c = np.asarray(frame.world_to_camera, dtype=np.float64)
    depth = np.asarray(points, dtype=np.float64) @ w2c[2, :3] + w2c[2, 3]
    ahead = depth[depth > 0]
    distance = float(np.median(ahead)) if len(ahead) else 1.0
    fov = float(2 * np.arctan(frame.height / (2 * frame.K[1, 1])))
    return StartView(_xyz(centre), _xyz(centre + distance * forward), _xyz(up), fov)


def label_text(rank: int, probability: float) -> str:
    """A box's label: its rank and p(relevant), e.g. ``#1 0.98`` (the legend names the object)."""
    return f"#{rank + 1} {probability:.2f}"


def box_top(centre: np.ndarray, rotation: np.ndarray, extents: np.ndarray, up: np.ndarray) -> np.ndarray:
    """The corner of an oriented box highest along `up` (where its label starts)."""
    rotation = np.asarray(rotation, dtype=np.float64)
    signs = np.where(rotation.T @ np.asarray(up, dtype=np.float64) >= 0, 1.0, -1.0)
    return np.asarray(centre, dtype=np.float64) + rotation @ (
        signs * np.asarray(extents, dtype=np.float64) / 2
    )


def label_anchors(tops: np.ndarray, texts: list[str], frame: Frame) -> np.ndarray:
    """(K, 3) world anchors (a label's bottom-left corner) for labels whose boxes' tops are
    `tops` (K, 3), in rank order, stacked so that none overlaps another in `frame`'s view."""
    tops = np.asarray(tops, dtype=np.float64).reshape(-1, 3)
    w2c = np.asarray(frame.world_to_camera, dtype=np.float64)
    up = -np.asarray(frame.camera_to_world, dtype=np.float64)[:3, 1]
    fy, cy = float(frame.K[1, 1]), float(frame.K[1, 2])
    fx, cx = float(frame.K[0, 0]), float(frame.K[0, 2])
    unit = float(frame.height)  # sizes are shares of the view's height
    placed: list[tuple[float, float, float, float]] = []  # (left, right, top, bottom) in pixels
    anchors = tops.copy()
    for i, (top, text) in enumerate(zip(tops, texts, strict=True)):
        cam = w2c[:3, :3] @ top + w2c[:3, 3]
        if cam[2] <= 1e-9:
            continue  # behind the start camera: it cannot overlap anything there
        u, v = fx * cam[0] / cam[2] + cx, fy * cam[1] / cam[2] + cy
        width, height = len(text) * LABEL_CHAR_WIDTH * unit, LABEL_HEIGHT * unit
        bottom = v
        moved = True
        while moved:
            moved = False
            for left, right, upper, lower in placed:
                if u < right and left < u + width and bottom - height < lower and upper < bottom:
                    bottom = upper - LABEL_GAP * unit  # just above that label
                    moved = True
        placed.append((u, u + width, bottom - height, bottom))
        anchors[i] = top + up * (v - bottom) * cam[2] / fy
    return anchors
