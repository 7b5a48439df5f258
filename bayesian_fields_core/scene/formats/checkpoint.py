"""gsplat `simple_trainer` checkpoints (`ckpts/ckpt_<step>_rank<r>.pt`).

The trainer saves `{"step": int, "splats": state_dict}` with tensors means (N, 3), scales (N, 3,
log), quats (N, 4, w x y z, unnormalised), opacities (N, logit), sh0 (N, 1, 3) and shN (N, K-1, 3),
in its normalised world frame. Read with `torch.load(weights_only=True)` only: PyTorch's
restricted unpickler, which builds tensors and plain containers and refuses any other object.
Nothing else in the project unpickles. The CLI reads checkpoints (a user's own file on their own
machine); the service does not accept them (their row in `scene.formats.registry` says
`upload=False`): a `.pt` is still a pickle stream, and the upload edge takes only plain data.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats.common import gaussians, require_count
from bayesian_fields_core.scene.types import Gaussians

CKPT = re.compile(r"ckpt_(\d+)(?:_rank(\d+))?\.pt$")
KEYS = ("means", "scales", "quats", "opacities", "sh0")


def read_checkpoint(path: Path, max_gaussians: int) -> Gaussians:
    """The splat of a gsplat checkpoint, in the trainer's (normalised) frame."""
    import torch

    try:
        doc = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # the unpickler raises many kinds; each means "not a plain checkpoint"
        raise InputError(
            f"not a gsplat checkpoint readable with weights_only=True ({type(exc).__name__}: {str(exc)[:200]})",
            source=str(path),
        ) from None
    splats = doc.get("splats") if isinstance(doc, dict) else None
    if not isinstance(splats, dict) or not all(k in splats for k in KEYS):
        raise InputError(f"checkpoint has no 'splats' dict with {', '.join(KEYS)}", source=str(path))
    arrays = {}
    for key in (*KEYS, "shN"):
        value = splats.get(key)
        if value is None:
            continue
        if not isinstance(value, torch.Tensor):
            raise InputError(f"splats[{key!r}] is not a tensor", source=str(path))
        arrays[key] = value.detach().to(torch.float32).numpy()
    n = arrays["means"].shape[0]
    require_count(n, max_gaussians, source=path)
    shapes = {"means": (n, 3), "scales": (n, 3), "quats": (n, 4), "opacities": (n,), "sh0": (n, 1, 3)}
    for key, shape in shapes.items():
        if arrays[key].shape != shape:
            raise InputError(
                f"splats[{key!r}] has shape {arrays[key].shape}, expected {shape}", source=str(path)
            )
    sh = arrays["sh0"]
    if "shN" in arrays and arrays["shN"].shape[1]:
        rest = arrays["shN"]
        if rest.shape[0] != n or rest.shape[2] != 3 or rest.shape[1] not in (3, 8, 15):
            raise InputError(f"splats['shN'] has shape {rest.shape}", source=str(path))
        sh = np.concatenate([sh, rest], axis=1)
    return gaussians(arrays["means"], arrays["scales"], arrays["quats"], arrays["opacities"], sh)
