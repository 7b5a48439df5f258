"""Writers for the fixtures no ecosystem tool here can produce: an INRIA PLY coloured by
red/green/blue (the layout of `ns-export gaussian-splat --ply-color-mode rgb`), a gsplat
checkpoint (`torch.save` of the trainer's `{"step", "splats"}` dict of tensors) and `.splat`
(`scene.formats.antimatter.write_antimatter`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayesian_fields_core.scene.formats.common import SH_C0
from bayesian_fields_core.scene.types import Gaussians


def write_rgb_ply(path: Path, g: Gaussians) -> None:
    """x y z nx ny nz red green blue (uchar) opacity scale_* rot_*: nerfstudio's rgb mode order."""
    n = len(g)
    fields = [(a, "<f4") for a in ("x", "y", "z", "nx", "ny", "nz")]
    fields += [(c, "u1") for c in ("red", "green", "blue")]
    fields += [("opacity", "<f4")] + [(f"scale_{i}", "<f4") for i in range(3)]
    fields += [(f"rot_{i}", "<f4") for i in range(4)]
    rows = np.zeros(n, dtype=fields)
    for i, a in enumerate("xyz"):
        rows[a] = g.means[:, i]
    colour = np.clip(0.5 + SH_C0 * g.sh[:, 0, :], 0.0, 1.0)
    for i, c in enumerate(("red", "green", "blue")):
        rows[c] = np.round(colour[:, i] * 255.0)
    rows["opacity"] = g.opacity_logits
    for i in range(3):
        rows[f"scale_{i}"] = g.log_scales[:, i]
    for i in range(4):
        rows[f"rot_{i}"] = g.quats[:, i]
    types = {"<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property {types[t]} {name}" for name, t in fields] + ["end_header"]
    path.write_bytes(("\n".join(header) + "\n").encode() + rows.tobytes())


def write_gsplat_checkpoint(path: Path, g: Gaussians, *, step: int = 29999) -> None:
    """The dict gsplat's simple_trainer saves: {"step", "splats": {means, scales, quats,
    opacities, sh0, shN}} as torch tensors."""
    import torch

    splats = {
        "means": torch.from_numpy(g.means.copy()),
        "scales": torch.from_numpy(g.log_scales.copy()),
        "quats": torch.from_numpy(g.quats.copy()),
        "opacities": torch.from_numpy(g.opacity_logits.copy()),
        "sh0": torch.from_numpy(g.sh[:, :1, :].copy()),
        "shN": torch.from_numpy(g.sh[:, 1:, :].copy()),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"step": step, "splats": splats}, path)


def sh3_sample(ply: Path, n: int = 2000) -> Gaussians:
    """The first `n` Gaussians of a splat with SH degree 3 bands drawn uniformly in [-0.3, 0.3]
    (seeded): the source of the `sh3.*` fixtures, which exercise the readers' SH decoding."""
    from bayesian_fields_core.scene.ply import read_ply

    g = read_ply(ply).subset(np.arange(n))
    sh = np.zeros((n, 16, 3), np.float32)
    sh[:, 0] = g.sh[:, 0]
    sh[:, 1:] = np.random.default_rng(0).uniform(-0.3, 0.3, (n, 15, 3))
    g.sh = sh
    g.extra = {}
    return g
