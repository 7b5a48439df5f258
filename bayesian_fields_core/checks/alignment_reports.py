"""What the alignment checks report: typed, so the CLI, the API and the worker show the same.

Kept apart from the checks themselves (`alignment`, `alignment_render`) so both can build them
without importing each other.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel

from bayesian_fields_core.errors import InputError


class FrameShares(BaseModel):
    """Opacity-weighted shares of the sampled Gaussians for one frame."""

    frame: str
    in_front: float
    in_frustum: float


class GeometryReport(BaseModel):
    gaussians_sampled: int
    frames_checked: int
    in_front_share: float  # mean over frames of the share with camera z > 0
    frustum_share: float  # share inside at least one frustum
    flipped_frustum_share: float  # the same with OpenGL <-> OpenCV flipped cameras
    splat_extent: float
    camera_baseline: float
    extent_ratio: float | None
    frames: list[FrameShares]


class FrameScore(BaseModel):
    frame: str
    score: float  # alpha-weighted ZNCC of the blurred grey render and photo
    coverage: float  # mean rendered alpha
    best_match: str  # the checked photo this render correlates best with


class RenderReport(BaseModel):
    frames: list[FrameScore]
    score: float  # median of the frames' scores
    coverage: float  # median of the frames' coverages
    mismatched_frames: int  # renders that match another checked photo better than their own
    flipped_score: float | None  # median score with flipped cameras (computed only on failure)
    width: int
    height: int
    seconds: float


class AlignmentReport(BaseModel):
    """Every number of the check plus the verdict; `cause` is the one-line refusal when failed."""

    passed: bool
    cause: str | None
    geometry: GeometryReport
    rendered: RenderReport | None
    seconds: float  # what the check took when it ran
    cached: bool = False  # read back from the job cache (`job/alignment_cache.py`), not run now

    def summary(self) -> str:
        """One line for a console: the score and the shares."""
        parts = [f"{100 * self.geometry.frustum_share:.0f}% of the splat in the camera frustums"]
        if self.geometry.extent_ratio is not None:
            parts.append(f"extent {self.geometry.extent_ratio:.2f}x the camera baseline")
        if self.rendered is not None:
            r = self.rendered
            parts.insert(0, f"render-vs-photo score {r.score:.2f} over {len(r.frames)} frames")
        verdict = "ok" if self.passed else "FAILED"
        took = "cached" if self.cached else f"{self.seconds:.2f} s"
        return f"alignment {verdict}: {', '.join(parts)} ({took})"

    def raise_if_failed(self) -> AlignmentReport:
        if not self.passed:
            raise InputError(self.cause or "the splat does not line up with its cameras", source="alignment")
        return self


def spread_indices(count: int, k: int) -> list[int]:
    """k indices (or all when count <= k) spread evenly from the first to the last frame."""
    if count <= k:
        return list(range(count))
    return sorted({int(round(x)) for x in np.linspace(0, count - 1, k)})
