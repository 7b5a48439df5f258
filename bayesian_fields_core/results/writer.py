"""Write a `Result` through a `Store` (see `docs/results-format.md`).

The arrays and exports are written first and `summary.json` last: the summary names every other
file with its checksum, so its presence marks a complete result and a crash mid-write leaves
nothing a reader would accept.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InputError
from ..params import default
from ..scene.types import Frame, Gaussians
from ..store import Store, put_json
from .export import put_ply, recolour, task_recolour
from .format import (
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
)
from .previews import CONTACT_SHEET_KEY, PREVIEW_DIR, contact_sheet, render_previews


def normalise_prefix(prefix: str) -> str:
    """'' or a key prefix ending in '/'."""
    return prefix if not prefix or prefix.endswith("/") else prefix + "/"


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
) -> dict[str, int]:
    """Write `result` under `prefix`; with `gaussians` (the scene's splat) and `export_ply`, also the
    per-object, per-task and recoloured-scene `.ply` exports; with `gaussians`, `frames` and
    `preview_max_side`, one preview PNG per task and a contact sheet (`results.previews`). `scene`
    (free-form JSON: where the scene came from) is recorded so a viewer can find the splat again.
    Returns {key relative to prefix: bytes written}.

    Stale files of an earlier result under the same prefix are removed first, so the directory
    always holds exactly what the summary describes.
    """
    result.validate()
    prefix = normalise_prefix(prefix)
    if gaussians is not None and len(gaussians) != result.num_gaussians:
        raise InputError(
            f"write_result: the splat has {len(gaussians)} Gaussians but object_ids has {result.num_gaussians}"
        )
    store.delete(prefix + SUMMARY_KEY)  # first: a half-rewritten result is never readable
    store.delete_prefix(prefix + "exports/")
    store.delete_prefix(prefix + PREVIEW_DIR)
    sizes: dict[str, int] = {}

    def put(name: str, data: bytes) -> None:
        store.put_bytes(prefix + name, data)
        sizes[name] = len(data)

    arrays: dict[str, Any] = {}
    stored_ids, sentinel = encode_ids(result.object_ids)
    arrays["object_ids"], data = encode_array(stored_ids, file=OBJECT_IDS_KEY, sentinel=sentinel)
    put(OBJECT_IDS_KEY, data)
    if result.primitive_ids is not None:
        stored_prims, prim_sentinel = encode_ids(result.primitive_ids)
        arrays["primitive_ids"], data = encode_array(
            stored_prims, file=PRIMITIVE_IDS_KEY, sentinel=prim_sentinel
        )
        put(PRIMITIVE_IDS_KEY, data)
    else:
        store.delete(prefix + PRIMITIVE_IDS_KEY)
    probs = np.asarray(result.probabilities, dtype=np.float32)
    arrays["probabilities"], data = encode_array(probs, file=PROBABILITIES_KEY)
    put(PROBABILITIES_KEY, data)
    if result.relevance is not None:
        rel = np.asarray(result.relevance, dtype=np.float32)
        arrays["relevance"], data = encode_array(rel, file=RELEVANCE_KEY)
        put(RELEVANCE_KEY, data)
    else:
        store.delete(prefix + RELEVANCE_KEY)

    exports: dict[str, Any] = {"objects": {}, "scene": None, "tasks": {}}
    if gaussians is not None and export_ply:
        ids = np.asarray(result.object_ids)
        for object_id in sorted({o.object_id for objs in result.selections.values() for o in objs}):
            key = object_export_key(object_id)
            sizes[key] = put_ply(store, prefix + key, gaussians.subset(ids == object_id))
            exports["objects"][str(object_id)] = key
        sizes[SCENE_EXPORT_KEY] = put_ply(
            store, prefix + SCENE_EXPORT_KEY, recolour(gaussians, ids, result.num_objects)
        )
        exports["scene"] = SCENE_EXPORT_KEY
        for t, task in enumerate(result.tasks):
            key = task_export_key(t)
            chosen = [o.object_id for o in result.selections.get(task, [])]
            sizes[key] = put_ply(store, prefix + key, task_recolour(gaussians, ids, chosen))
            exports["tasks"][task] = key

    previews: dict[str, Any] = {"tasks": [], "contact_sheet": None}
    if gaussians is not None and frames and preview_max_side:
        rendered = render_previews(result, gaussians, frames, max_side=preview_max_side)
        for preview in rendered:
            put(preview.key, preview.png)
            previews["tasks"].append(preview.entry())
        if rendered:
            put(CONTACT_SHEET_KEY, contact_sheet(rendered))
            previews["contact_sheet"] = CONTACT_SHEET_KEY

    def describe(obj: SelectedObject) -> dict[str, Any]:
        return {**obj.to_dict(), "export": exports["objects"].get(str(obj.object_id))}

    summary = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "tasks": list(result.tasks),
        "probability_columns": [*result.tasks, NULL_TASK],
        "counts": result.counts(),
        "arrays": arrays,
        "selections": [_selection_entry(result, task, describe) for task in result.tasks],
        "exports": exports,
        "previews": previews,
        "scene": scene,
        "parameters": result.parameters,
        "models": result.models,
        "timings_s": {k: float(v) for k, v in result.timings_s.items()},
    }
    if result.splat_to_capture is not None or result.layout:
        summary["frames"] = {
            "layout": result.layout,
            "splat_to_capture": None
            if result.splat_to_capture is None
            else np.asarray(result.splat_to_capture, dtype=np.float64).tolist(),
        }
    put_json(store, prefix + SUMMARY_KEY, summary)
    sizes[SUMMARY_KEY] = store.size(prefix + SUMMARY_KEY)
    return sizes
