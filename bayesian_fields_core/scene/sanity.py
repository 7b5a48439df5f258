"""Plausibility checks for a splat whose values are finite but meaningless.

A splat can parse cleanly and still make every downstream number meaningless: a zero quaternion
has no rotation (normalising it gives NaN inside the renderer), a log-scale of 100 overflows the
covariance, a position of 1e12 has no float32 precision left. Such files used to run to a
"succeeded" job with garbage results. The thresholds live here, once, and are documented:

Refused (InputError naming the property and how many Gaussians):
  * a quaternion (rot_0..3) of length below `MIN_QUATERNION_NORM`;
  * a log-scale (scale_0..2) outside `LOG_SCALE_RANGE` (exp(30) ~ 1e13 units wide; its square
    nears float32 overflow in the covariance; exp(-40) squared nears float32 underflow);
  * a coordinate (x, y, z) beyond `MAX_ABS_POSITION` (float32 steps there exceed one unit).
Warned (returned by `splat_warnings`; the upload summary lists them under "warnings"):
  * every Gaussian nearly transparent (opacity below `MIN_VISIBLE_OPACITY`): nothing renders;
  * all means at one point (no spatial extent);
  * more than `MAX_HUGE_FRACTION` of the Gaussians wider (largest std) than the whole scene.
"""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.types import Gaussians

MIN_QUATERNION_NORM = 1e-8
LOG_SCALE_RANGE = (-40.0, 30.0)
MAX_ABS_POSITION = 1e7
MIN_VISIBLE_OPACITY = 1.0 / 255.0
MAX_HUGE_FRACTION = 0.01


def check_splat(g: Gaussians, *, source: str) -> None:
    """Refuse the degenerate cases listed in the module docstring (raises InputError)."""
    raise_degenerate(degenerate_counts(g), source=source)


def degenerate_counts(g: Gaussians) -> tuple[int, int, int]:
    """(zero-length quaternions, log-scales out of range, positions too far) over `g`: counts
    that add up over chunks, so a streamed check gives the message of a whole-file one."""
    zero_quats = int((np.linalg.norm(g.quats.astype(np.float64), axis=1) < MIN_QUATERNION_NORM).sum())
    lo, hi = LOG_SCALE_RANGE
    bad_scales = int(((g.log_scales < lo) | (g.log_scales > hi)).any(axis=1).sum())
    far = int((np.abs(g.means) > MAX_ABS_POSITION).any(axis=1).sum())
    return zero_quats, bad_scales, far


def raise_degenerate(counts: tuple[int, int, int], *, source: str) -> None:
    """InputError naming each degenerate case with its count (nothing when all are zero)."""
    zero_quats, bad_scales, far = counts
    lo, hi = LOG_SCALE_RANGE
    problems = []
    if zero_quats:
        problems.append(f"{zero_quats} Gaussians have a zero-length rotation quaternion (rot_0..3)")
    if bad_scales:
        problems.append(f"{bad_scales} Gaussians have a log-scale (scale_0..2) outside [{lo:g}, {hi:g}]")
    if far:
        problems.append(f"{far} Gaussians lie beyond |x|, |y| or |z| = {MAX_ABS_POSITION:g}")
    if problems:
        raise InputError("degenerate splat: " + "; ".join(problems), source=source)


def splat_extent(means: np.ndarray) -> float:
    """Largest axis span of the 1st-99th percentile box of the means (floaters ignored)."""
    lo, hi = np.percentile(means, [1.0, 99.0], axis=0)
    return float((hi - lo).max())


def huge_count(log_scales: np.ndarray, extent: float) -> int:
    """How many Gaussians have a largest std wider than `extent`."""
    return int((np.exp(log_scales.max(axis=1).astype(np.float64)) > extent).sum())


def splat_warnings(g: Gaussians) -> list[str]:
    """Human-readable warnings for a splat that passed `check_splat` but looks meaningless."""
    n = len(g)
    if n == 0:
        return []
    extent = splat_extent(g.means)
    return warnings_from(n, float(g.opacities.max()), extent, huge_count(g.log_scales, extent))


def warnings_from(n: int, max_opacity: float, extent: float, huge: int) -> list[str]:
    """The warnings of `splat_warnings` from its statistics (what a streamed scan gathers)."""
    warnings = []
    if max_opacity < MIN_VISIBLE_OPACITY:
        warnings.append(f"every Gaussian has opacity below {MIN_VISIBLE_OPACITY:.4f}; nothing will render")
    if n > 1 and extent == 0.0:
        warnings.append("all Gaussians sit at the same point; the splat has no spatial extent")
    elif extent > 0.0:
        share = huge / n
        if share > MAX_HUGE_FRACTION:
            warnings.append(
                f"{share:.1%} of the Gaussians are wider than the whole scene ({extent:.3g} units)"
            )
    return warnings
