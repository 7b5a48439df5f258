"""Moving fusion's arrays between the host and the device the fusion state lives on.

The fusion ops are written once, as torch ops, and run wherever their tensors are: the CPU for the
CLI and CPU workers, a GPU for GPU workers. Inputs arrive as numpy arrays (the perception cache,
input depth images, camera matrices) or as tensors (rendered depth); `as_tensor` turns both into
tensors on one device without copying a CPU array, and `to_numpy` brings results back (again
without a copy when they are already on the CPU).
"""

from __future__ import annotations

import numpy as np
import torch


def as_tensor(
    array: np.ndarray | torch.Tensor, device: torch.device | str, dtype: torch.dtype | None = None
) -> torch.Tensor:
    """`array` as a tensor on `device` (and of `dtype` when given); shares memory where it can."""
    if isinstance(array, torch.Tensor):
        return array.to(device=device, dtype=dtype)
    return torch.as_tensor(np.asarray(array), device=device, dtype=dtype)


def to_numpy(tensor: torch.Tensor) -> np.ndarray:
    """A tensor's values as a numpy array on the host (a view when it is already there)."""
    return tensor.detach().cpu().numpy()


CPU_THREADS = 1
"""torch intra-op threads for the fusion ops on the CPU (`fusion_threads`).

Each op is one streaming pass over the Gaussians or the pairs ending in a barrier; on a shared
machine idle OpenMP threads spinning at those barriers cost far more than a second core saves
(bench_fusion, 400k Gaussians on 2 busy cores: ~0.5 s per frame on two threads, ~30 ms on one),
and the numpy code these ops replaced ran on one core too."""


def fusion_threads(device: torch.device | str) -> int | None:
    """Intra-op threads to run the fusion ops with on `device`: `CPU_THREADS` on the CPU; None
    (torch's own setting) elsewhere, where the host threads only launch kernels."""
    return CPU_THREADS if torch.device(device).type == "cpu" else None
