"""A small seeded scene for the clustering regression test: Gaussians in blobs on a floor, frames
of masks at varying granularity with OR-phi flags, and fused probabilities per task.

Shapes: means (N, 3) float32; frames: list of (gaussian_ids (n,), mask_ids (n,), accepted (M,));
probabilities / logodds (N, T) float32. Everything comes from one `numpy.random.default_rng(seed)`,
so the scene is the same wherever the test runs.
"""

from __future__ import annotations

import numpy as np

N_BLOBS = 14
BLOB_POINTS = 260
FLOOR_POINTS = 1200
FRAMES = 50
TASKS = 4
GRID = 4


def cluster_scene(
    seed: int = 7,
) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray, np.ndarray]], np.ndarray]:
    """(means (N, 3), frames, probabilities (N, T)) of the regression scene."""
    rng = np.random.default_rng(seed)
    centres = np.column_stack([rng.uniform(-2, 2, (N_BLOBS, 2)), rng.uniform(0.1, 0.5, N_BLOBS)])
    spread = rng.uniform(0.05, 0.25, N_BLOBS)
    blob = np.repeat(np.arange(N_BLOBS), BLOB_POINTS)
    on_blobs = centres[blob] + rng.normal(size=(len(blob), 3)) * spread[blob, None]
    floor = np.column_stack([rng.uniform(-2.5, 2.5, (FLOOR_POINTS, 2)), rng.normal(0, 0.01, FLOOR_POINTS)])
    means = np.concatenate([on_blobs, floor]).astype(np.float32)
    n = len(means)
    blob_of = np.concatenate([blob, np.full(FLOOR_POINTS, -1)])
    cell = np.minimum(((floor[:, :2] + 2.5) / 5.0 * GRID).astype(np.int64), GRID - 1)
    cell_of = np.concatenate([np.full(len(blob), -1), cell[:, 1] * GRID + cell[:, 0]])
    side = np.concatenate([on_blobs[:, 0] > centres[blob, 0], np.zeros(FLOOR_POINTS, bool)])

    frames = []
    for _ in range(FRAMES):
        visible = np.flatnonzero(rng.random(n) < 0.5)
        split = rng.random(N_BLOBS) < 0.35
        merge_cells = rng.random(GRID * GRID) < 0.3
        cell_part = np.where(merge_cells, np.arange(GRID * GRID) // 2 * 2, np.arange(GRID * GRID))
        part = np.where(
            blob_of >= 0,
            blob_of + N_BLOBS * (split[np.maximum(blob_of, 0)] & side),
            2 * N_BLOBS + cell_part[np.maximum(cell_of, 0)],
        )[visible]
        ids, mask_ids = np.unique(part, return_inverse=True)
        accepted = rng.random(len(ids)) < 0.9
        frames.append((visible.astype(np.int64), mask_ids.astype(np.int64), accepted))

    blob_task = rng.integers(-1, TASKS, N_BLOBS)  # -1: relevant to no task
    base = np.full((n, TASKS), 0.05)
    relevant = blob_of >= 0
    task = np.where(relevant, blob_task[np.maximum(blob_of, 0)], -1)
    rows = np.flatnonzero(task >= 0)
    base[rows, task[rows]] = rng.uniform(0.6, 0.9, N_BLOBS)[blob_of[rows]]
    noise = rng.normal(0, 0.02, base.shape) * relevant[:, None]  # the floor stays at the prior exactly
    probabilities = np.clip(base + noise, 0.001, 0.999).astype(np.float32)
    return means, frames, probabilities
