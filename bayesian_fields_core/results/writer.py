"""Write a `Result` through a `Store` (see `docs/results-format.md`).

The arrays and exports are written first and `summary.json` last: the summary names every other
file with its checksum, so its presence marks a complete result and a crash mid-write leaves
nothing a reader would accept.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import Store, put_json
from bayesian_fields_core.objects.timing import StepTimer
from bayesian_fields_core.params import default
from bayesian_fields_core.results.export import put_ply, put_task_plys, recolour
from bayesian_fields_core.results.format import (
    FORMAT_NAME,
    FORMAT_VERSION,
    NULL_TASK,
    OBJECT_EXPORT_DIR,
    OBJECT_IDS_KEY,
    PRIMITIVE_IDS_KEY,
    PROBABILITIES_KEY,
    RELEVANCE_KEY,
    SCENE_EXPORT_KEY,
    SUMMARY_KEY,
    TASK_EXPORT_DIR,
    Result,
    SelectedObject,
    encode_array,
    encode_ids,
    normalise_prefix,
)
from bayesian_fields_core.results.previews import (
    CONTACT_SHEET_KEY,
    PREVIEW_DIR,
    contact_sheet,
    render_previews,
)
from bayesian_fields_core.scene.similarity import Similarity
from bayesian_fields_core.scene.types import Frame, Gaussians


def object_export_key(object_id: int) -> str:
    return f"{OBJECT_EXPORT_DIR}object_{object_id:05d}.ply"


def task_export_key(task_index: int) -> str:
    return f"{TASK_EXPORT_DIR}task_{task_index:02d}.ply"


def _selection_entry(result: Result, task: str, describe: Any) -> dict[str, Any]:
    """One task's summary entry: its ranked objects and, when it has no answer, why (1.3)."""
    entry: dict[str, Any] = {"task": task, "objects": [describe(o) for o in result.selections.get(task, [])]}
    if task in result.not_found:
        entry["not_found"] = result.not_found[task].to_dict()
    return entry


def write_result(
    store: Store,
    prefix: str,
    result: Result,
    *,
    gaussians: Gaussians | None = None,
    export_ply: bool = default("export_ply"),
    frames: list[Frame] | None = None,
    preview_max_side: int | None = None,
    scene: dict[str, Any] | None = None,
    timer: StepTimer | None = None,
) -> dict[str, int]:
    """Write `result` under `prefix`; with `gaussians` (the scene's splat) and `export_ply`, also the
    per-object, per-task and recoloured-scene `.ply` exports; with `gaussians`, `frames` and
    `preview_max_side`, one preview PNG per task and a contact sheet (`results.previews`). `scene`
    (free-form JSON: where the scene came from) is recorded so a viewer can find the splat again.
    Returns {key relative to prefix: bytes written}.

    Stale files of an earlier result under the same prefix are removed first, so the directory
    always holds exactly what the summary describes. `timer` gets the seconds of the steps
    "write" (arrays and summary), "exports" and "previews", which differ by orders of magnitude.
    """
    timer = timer or StepTimer()
    prefix = normalise_prefix(prefix)
    sizes: dict[str, int] = {}

    def put(name: str, data: bytes) -> None:
        store.put_bytes(prefix + name, data)
        sizes[name] = len(data)

    with timer("write"):
        arrays = _write_arrays(store, prefix, result, gaussians, put)
    exports: dict[str, Any] = {"objects": {}, "scene": None, "tasks": {}}
    with timer("exports"):
        if gaussians is not None and export_ply:
            _write_exports(store, prefix, result, gaussians, exports, sizes)
    previews: dict[str, Any] = {"tasks": [], "contact_sheet": None}
    with timer("previews"):
        if gaussians is not None and frames and preview_max_side:
            rendered = render_previews(
                result,
                _in_camera_frame(result, gaussians),
                frames,
                max_side=preview_max_side,
                near_plane=_render_near(result),
            )
            for preview in rendered:
                put(preview.key, preview.png)
                previews["tasks"].append(preview.entry())
            if rendered:
                put(CONTACT_SHEET_KEY, contact_sheet(rendered))
                previews["contact_sheet"] = CONTACT_SHEET_KEY
    with timer("write"):
        put_json(store, prefix + SUMMARY_KEY, _summary(result, arrays, exports, previews, scene))
        sizes[SUMMARY_KEY] = store.size(prefix + SUMMARY_KEY)
    return sizes


def _in_camera_frame(result: Result, gaussians: Gaussians) -> Gaussians:
    """The splat file's Gaussians mapped into the cameras' frame, where the previews' frames are
    (an unmapped nerfstudio / gsplat splat would be rendered off to the side of its cameras)."""
    if result.splat_to_capture is None:
        return gaussians
    return Similarity.from_matrix(result.splat_to_capture, source="splat_to_capture").gaussians(gaussians)


def _render_near(result: Result) -> float | None:
    """The run's renderer near plane (a fraction of the scene scale), None for older results."""
    lengths = (result.scene_scale or {}).get("lengths") or {}
    near = lengths.get("render_near")
    return None if near is None else float(near)


def _write_arrays(
    store: Store, prefix: str, result: Result, gaussians: Gaussians | None, put: Callable[[str, bytes], None]
) -> dict[str, Any]:
    """Remove what an earlier result left, then write the arrays; returns their descriptions."""
    result.validate()
    if gaussians is not None and len(gaussians) != result.num_gaussians:
        raise InputError(
            f"write_result: the splat has {len(gaussians)} Gaussians but object_ids has {result.num_gaussians}"
        )
    store.delete(prefix + SUMMARY_KEY)  # first: a half-rewritten result is never readable
    store.delete_prefix(prefix + "exports/")
    store.delete_prefix(prefix + PREVIEW_DIR)
    # (name, file, array, sentinel) of every array stored; encoded concurrently (zlib and lzma
    # release the GIL, and the two per-Gaussian id arrays dominate the writing time)
    jobs: list[tuple[str, str, np.ndarray, int | None]] = [
        ("object_ids", OBJECT_IDS_KEY, *encode_ids(result.object_ids))
    ]
    if result.primitive_ids is not None:
        jobs.append(("primitive_ids", PRIMITIVE_IDS_KEY, *encode_ids(result.primitive_ids)))
    else:
        store.delete(prefix + PRIMITIVE_IDS_KEY)
    jobs.append(
        ("probabilities", PROBABILITIES_KEY, np.asarray(result.probabilities, dtype=np.float32), None)
    )
    if result.relevance is not None:
        jobs.append(("relevance", RELEVANCE_KEY, np.asarray(result.relevance, dtype=np.float32), None))
    else:
        store.delete(prefix + RELEVANCE_KEY)
    with ThreadPoolExecutor(max_workers=min(len(jobs), os.cpu_count() or 1)) as pool:
        encoded = list(pool.map(lambda job: encode_array(job[2], file=job[1], sentinel=job[3]), jobs))
    arrays: dict[str, Any] = {}
    for (name, file, _, _), (desc, data) in zip(jobs, encoded, strict=True):
        arrays[name] = desc
        put(file, data)
    return arrays


def _write_exports(
    store: Store,
    prefix: str,
    result: Result,
    gaussians: Gaussians,
    exports: dict[str, Any],
    sizes: dict[str, int],
) -> None:
    """The .ply exports: each selected object, the recoloured scene, one file per task."""
    ids = np.asarray(result.object_ids)
    for object_id in sorted({o.object_id for objs in result.selections.values() for o in objs}):
        key = object_export_key(object_id)
        sizes[key] = put_ply(store, prefix + key, gaussians.subset(ids == object_id))
        exports["objects"][str(object_id)] = key
    sizes[SCENE_EXPORT_KEY] = put_ply(
        store, prefix + SCENE_EXPORT_KEY, recolour(gaussians, ids, result.num_objects)
    )
    exports["scene"] = SCENE_EXPORT_KEY
    keys = [task_export_key(t) for t in range(len(result.tasks))]
    chosen = [[o.object_id for o in result.selections.get(task, [])] for task in result.tasks]
    written = put_task_plys(store, [prefix + k for k in keys], gaussians, ids, chosen)
    for task, key, size in zip(result.tasks, keys, written, strict=True):
        sizes[key] = size
        exports["tasks"][task] = key


def _summary(
    result: Result,
    arrays: dict[str, Any],
    exports: dict[str, Any],
    previews: dict[str, Any],
    scene: dict[str, Any] | None,
) -> dict[str, Any]:
    """summary.json: names every file with its checksum (written last; see the module doc)."""

    keys = result.content_keys()

    def describe(obj: SelectedObject) -> dict[str, Any]:
        return {
            **obj.to_dict(),
            "export": exports["objects"].get(str(obj.object_id)),
            "key": keys[obj.object_id],
        }

    summary = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "tasks": list(result.tasks),
        "probability_columns": [*result.tasks, NULL_TASK],
        "counts": result.counts(),
        "arrays": arrays,
        "selections": [_selection_entry(result, task, describe) for task in result.tasks],
        "splat_digest": result.splat_digest,
        "object_keys": keys,
        "exports": exports,
        "previews": previews,
        "scene": scene,
        "parameters": result.parameters,
        "models": result.models,
        "timings_s": {k: float(v) for k, v in result.timings_s.items()},
    }
    if result.splat_to_capture is not None or result.layout or result.capture_to_world is not None:
        summary["frames"] = frames_block(result)
    if result.scene_scale is not None:
        summary["scene_scale"] = result.scene_scale
    if result.ranked_by:
        summary["ranked_by"] = result.ranked_by
    return summary


FRAME_NAMES = {
    "splat": "the splat file's own frame: selections[].objects[].centroid / box",
    "capture": "the cameras' frame the run computed in: capture_frame blocks (only when it is not the splat's)",
    "world": (
        "the data's own world frame (COLMAP's), undoing nerfstudio's applied_transform: world_frame "
        "blocks (only when it is not the cameras' frame)"
    ),
}
"""What each coordinate frame of a result is, written into summary.json's `frames.names`."""


def frames_block(result: Result) -> dict[str, Any]:
    """summary.json's `frames`: the layout, the transforms between the frames and their names."""

    def matrix(m: np.ndarray | None) -> list[list[float]] | None:
        return None if m is None else np.asarray(m, dtype=np.float64).tolist()

    names = {"splat": FRAME_NAMES["splat"]}
    if result.splat_to_capture is not None:
        names["capture"] = FRAME_NAMES["capture"]
    if result.capture_to_world is not None:
        names["world"] = FRAME_NAMES["world"]
    return {
        "layout": result.layout,
        "splat_to_capture": matrix(result.splat_to_capture),
        "capture_to_world": matrix(result.capture_to_world),
        "names": names,
    }
