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
    problems = []
    zero_quats = int((np.linalg.norm(g.quats.astype(np.float64), axis=1) < MIN_QUATERNION_NORM).sum())
    if zero_quats:
        problems.append(f"{zero_quats} Gaussians have a zero-length rotation quaternion (rot_0..3)")
    lo, hi = LOG_SCALE_RANGE
    bad_scales = int(((g.log_scales < lo) | (g.log_scales > hi)).any(axis=1).sum())
    if bad_scales:
        problems.append(f"{bad_scales} Gaussians have a log-scale (scale_0..2) outside [{lo:g}, {hi:g}]")
    far = int((np.abs(g.means) > MAX_ABS_POSITION).any(axis=1).sum())
    if far:
        problems.append(f"{far} Gaussians lie beyond |x|, |y| or |z| = {MAX_ABS_POSITION:g}")
    if problems:
        raise InputError("degenerate splat: " + "; ".join(problems), source=source)


def splat_warnings(g: Gaussians) -> list[str]:
    """Human-readable warnings for a splat that passed `check_splat` but looks meaningless."""
    n = len(g)
    if n == 0:
        return []
    warnings = []
    if float(g.opacities.max()) < MIN_VISIBLE_OPACITY:
        warnings.append(f"every Gaussian has opacity below {MIN_VISIBLE_OPACITY:.4f}; nothing will render")
    lo, hi = np.percentile(g.means, [1.0, 99.0], axis=0)
    extent = float((hi - lo).max())
    if n > 1 and extent == 0.0:
        warnings.append("all Gaussians sit at the same point; the splat has no spatial extent")
    elif extent > 0.0:
        huge = float((np.exp(g.log_scales.max(axis=1).astype(np.float64)) > extent).mean())
        if huge > MAX_HUGE_FRACTION:
            warnings.append(
                f"{huge:.1%} of the Gaussians are wider than the whole scene ({extent:.3g} units)"
            )
    return warnings
