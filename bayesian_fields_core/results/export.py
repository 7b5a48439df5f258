"""Splat exports of a result: one `.ply` per selected object and a recoloured whole scene.

Both are ordinary INRIA-layout splats, so any splat viewer opens them with no plug-in: the object
files are the object's Gaussians with every attribute untouched; the scene file gives each object
one flat, distinct colour (degree-0 SH only, f_rest zeroed so the colour does not change with the
view) and dims everything else to grey. Per-task files colour one task's selected objects by rank.
Recoloured files carry an int32 `object_id` vertex property (-1 = none), so a viewer can filter.
"""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.geometry.spherical_harmonics import SH_C0
from bayesian_fields_core.job.store import Store
from bayesian_fields_core.results.colours import BACKGROUND_GREY, object_palette, rank_colour
from bayesian_fields_core.scene.ply import ply_rows
from bayesian_fields_core.scene.types import Gaussians


def recolour(gaussians: Gaussians, object_ids: np.ndarray, num_objects: int) -> Gaussians:
    """A copy of the splat with each object's Gaussians in its palette colour and the rest grey."""
    ids = np.asarray(object_ids)
    rgb = np.full((len(gaussians), 3), BACKGROUND_GREY, dtype=np.float32)
    inside = ids >= 0
    rgb[inside] = object_palette(num_objects)[ids[inside]]
    sh = np.zeros_like(gaussians.sh)
    sh[:, 0, :] = (rgb - 0.5) / SH_C0
    return Gaussians(
        means=gaussians.means,
        log_scales=gaussians.log_scales,
        quats=gaussians.quats,
        opacity_logits=gaussians.opacity_logits,
        sh=sh,
        extra={**gaussians.extra, "object_id": np.asarray(ids, dtype=np.int32)},
    )


def task_colour_sh(object_ids: np.ndarray, selected: list[int]) -> np.ndarray:
    """(N, 1, 3) float32 degree-0 SH of one task's colouring: its selected objects (ids in rank
    order) in their rank colour (`previews.RANK_COLOURS`), every other Gaussian grey."""

    ids = np.asarray(object_ids)
    rgb = np.full((len(ids), 3), BACKGROUND_GREY, dtype=np.float32)
    for rank, object_id in enumerate(selected):
        rgb[ids == object_id] = rank_colour(rank)
    return ((rgb - 0.5) / SH_C0)[:, None, :].astype(np.float32)


def task_recolour(gaussians: Gaussians, object_ids: np.ndarray, selected: list[int]) -> Gaussians:
    """A copy of the splat showing one task (`task_colour_sh`); `object_id` as in `recolour`."""
    ids = np.asarray(object_ids)
    # Degree 0 only: a flat colour needs no f_rest, and one file per task must stay small
    # (about 70 bytes a Gaussian instead of 248 for a degree-3 splat).
    return Gaussians(
        means=gaussians.means,
        log_scales=gaussians.log_scales,
        quats=gaussians.quats,
        opacity_logits=gaussians.opacity_logits,
        sh=task_colour_sh(ids, selected),
        extra={**gaussians.extra, "object_id": ids.astype(np.int32)},
    )


def put_task_plys(
    store: Store, keys: list[str], gaussians: Gaussians, object_ids: np.ndarray, selections: list[list[int]]
) -> list[int]:
    """Write `task_recolour(gaussians, object_ids, selections[t])` under `keys[t]` for every task;
    returns the sizes. The files share every column but the colour, so the rows are laid out once
    and only `f_dc_*` is rewritten per task (26 tasks x 400 k Gaussians: 0.7 GB written; laying out
    each file anew and writing it through a temporary file doubled the time)."""
    if not keys:
        return []
    header, rows = ply_rows(task_recolour(gaussians, object_ids, selections[0]))
    sizes = []
    for t, (key, selected) in enumerate(zip(keys, selections, strict=True)):
        if t:
            sh = task_colour_sh(object_ids, selected)
            for c in range(3):
                rows[f"f_dc_{c}"] = sh[:, 0, c]
        data = header + rows.tobytes()
        store.put_bytes(key, data)
        sizes.append(len(data))
    return sizes


def put_ply(store: Store, key: str, gaussians: Gaussians) -> int:
    """Write a splat through the store in one piece; returns its size in bytes."""
    header, rows = ply_rows(gaussians)
    data = header + rows.tobytes()
    store.put_bytes(key, data)
    return len(data)
