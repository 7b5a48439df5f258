"""Pieces every splat reader shares: the colour and opacity encodings, the count limit, and the
assembly of a `Gaussians` in the INRIA parameterisation that the rest of the pipeline reads.

Why one place: the web formats store *activated* values (linear scale, opacity in [0, 1], an sRGB
colour) where the INRIA PLY stores log-scales, logits and SH DC coefficients; converting in one
function keeps every reader's numbers comparable to the PLY it was made from.
"""

from __future__ import annotations

import shlex
from pathlib import Path

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.similarity import Similarity
from bayesian_fields_core.scene.types import Gaussians

SH_C0 = 0.28209479177387814
"""Degree-0 SH basis constant: colour = 0.5 + SH_C0 * f_dc."""
_OPACITY_EPS = 1e-6
"""Opacities are clipped to [eps, 1 - eps] before the logit, so a stored 0 or 255 stays finite."""

CONVERT_HINT = "npx @playcanvas/splat-transform {source} {target}"
"""The ecosystem's converter, named in refusals (it reads every web format we know of)."""
CONVERTED_SPLAT = "point_cloud.ply"
"""The name a conversion writes: the loader's first splat name (`layout.SPLAT_NAMES`)."""


def convert_command(path: Path) -> str:
    """The command that turns `path` into an INRIA PLY that the next run loads, for error messages.

    The output is `CONVERTED_SPLAT` beside the input: a scene folder's loader takes that name
    before any other file, so the unread original may stay where it is (a `<stem>.ply` beside it
    made the next run refuse "several splat files"). Paths are as given (a bare upload name stays
    bare), quoted for a shell."""
    target = path.with_name(CONVERTED_SPLAT)
    return CONVERT_HINT.format(source=shlex.quote(str(path)), target=shlex.quote(str(target)))


def logit(opacity: np.ndarray) -> np.ndarray:
    """Opacity in [0, 1] -> the PLY's logit, clipped so fully opaque / transparent stay finite."""
    p = np.clip(opacity.astype(np.float64), _OPACITY_EPS, 1.0 - _OPACITY_EPS)
    return np.log(p / (1.0 - p)).astype(np.float32)


def colour_to_dc(rgb: np.ndarray) -> np.ndarray:
    """Colour in [0, 1] -> SH DC coefficient (the inverse of 0.5 + SH_C0 * dc)."""
    return ((rgb.astype(np.float32) - 0.5) / SH_C0).astype(np.float32)


def require_count(count: int, max_gaussians: int, *, source: Path) -> None:
    """Refuse an empty splat or one over the limit before any array of that size is allocated."""
    if count <= 0:
        raise InputError("the splat has no Gaussians", source=str(source))
    if count > max_gaussians:
        raise InputError(
            f"{count} Gaussians exceed the limit max_gaussians={max_gaussians}", source=str(source)
        )


def nonfinite_counts(g: Gaussians) -> dict[str, int]:
    """Non-finite values per attribute (counts add up over chunks of rows)."""
    return {
        name: int((~np.isfinite(values)).sum())
        for name, values in (
            ("means", g.means),
            ("scales", g.log_scales),
            ("rotations", g.quats),
            ("opacities", g.opacity_logits),
            ("colours/SH", g.sh),
        )
    }


def raise_nonfinite(counts: dict[str, int], *, source: Path) -> None:
    """InputError naming every attribute with non-finite values (nothing when there are none)."""
    problems = [f"{n} in {name}" for name, n in counts.items() if n]
    if problems:
        raise InputError(f"non-finite values (NaN or inf): {', '.join(problems)}", source=str(source))


def require_finite(g: Gaussians, *, source: Path) -> None:
    """Non-finite values (a NaN in a float buffer) refused naming the attribute, like the PLY reader."""
    raise_nonfinite(nonfinite_counts(g), source=source)


def gaussians(
    means: np.ndarray,
    log_scales: np.ndarray,
    quats_wxyz: np.ndarray,
    opacity_logits: np.ndarray,
    sh: np.ndarray,
) -> Gaussians:
    """A `Gaussians` with every array float32 and contiguous (sh: (N, K, 3), K in 1, 4, 9, 16)."""

    def f32(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(a, dtype=np.float32)

    return Gaussians(
        means=f32(means),
        log_scales=f32(log_scales),
        quats=f32(quats_wxyz),
        opacity_logits=f32(opacity_logits).reshape(-1),
        sh=f32(sh),
    )


def sh_from_bands(dc: np.ndarray, rest: np.ndarray | None) -> np.ndarray:
    """(N, K, 3) SH from a DC (N, 3) and the higher bands (N, K-1, 3) or None (degree 0)."""
    n = dc.shape[0]
    if rest is None or rest.shape[1] == 0:
        return dc.reshape(n, 1, 3)
    return np.concatenate([dc.reshape(n, 1, 3), rest], axis=1)


def rotate_axes(g: Gaussians, axes: np.ndarray) -> Gaussians:
    """The Gaussians turned by a proper rotation (positions, quaternions and SH bands), used to
    bring a format's stored axes (SPZ's and glTF's) back to the PLY's frame."""
    return Similarity(1.0, np.asarray(axes, dtype=np.float64), np.zeros(3)).gaussians(g)


def sh_degree_for(coefficients: int, *, source: Path) -> int:
    """SH degree from the number of higher-band coefficients per channel (0, 3, 8 or 15)."""
    degrees = {0: 0, 3: 1, 8: 2, 15: 3}
    if coefficients not in degrees:
        raise InputError(
            f"{coefficients} higher SH coefficients per channel; a splat has 0, 3, 8 or 15",
            source=str(source),
        )
    return degrees[coefficients]
