"""Read a result written by `write_result`, validating the format version and every array, and
report the bytes each part takes (the paper's memory table)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.artifacts import RESULT_PREFIX
from bayesian_fields_core.job.store import ArtifactNotFound, LocalStore, Store
from bayesian_fields_core.results.format import (
    FORMAT_NAME,
    FORMAT_VERSION,
    OBJECT_IDS_KEY,
    PRIMITIVE_IDS_KEY,
    PROBABILITIES_KEY,
    RELEVANCE_KEY,
    SUMMARY_KEY,
    NotFound,
    Result,
    SelectedObject,
    decode_array,
    decode_ids,
    normalise_prefix,
)

if TYPE_CHECKING:  # this module stays numpy-only at import (module docstring)
    from bayesian_fields_core.scene.types import Gaussians


def _check_version(summary: dict[str, Any], where: str) -> None:
    if summary.get("format") != FORMAT_NAME:
        raise InputError(f"{where}: not a Bayesian Fields result (format={summary.get('format')!r})")
    version = str(summary.get("format_version", ""))
    major = version.split(".")[0]
    if not version or major != FORMAT_VERSION.split(".")[0]:
        raise InputError(
            f"{where}: format version {version!r} is not readable by this reader (reads {FORMAT_VERSION.split('.')[0]}.x)"
        )


def read_summary(store: Store, prefix: str) -> dict[str, Any]:
    """The parsed, version-checked `summary.json` of a result."""
    key = normalise_prefix(prefix) + SUMMARY_KEY
    try:
        summary = json.loads(store.get_bytes(key))
    except ArtifactNotFound:
        raise InputError(
            f"{key}: no result here (summary.json missing or the result is incomplete)"
        ) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{key}: not valid JSON ({exc})") from None
    if not isinstance(summary, dict):
        raise InputError(f"{key}: expected a JSON object")
    _check_version(summary, key)
    return summary


def _array(store: Store, prefix: str, summary: dict[str, Any], name: str, file: str) -> np.ndarray | None:
    desc = summary.get("arrays", {}).get(name)
    if desc is None:
        return None
    if desc.get("file") != file:
        raise InputError(f"{prefix}{SUMMARY_KEY}: array {name!r} must be stored in {file!r}")
    try:
        data = store.get_bytes(prefix + file)
    except ArtifactNotFound:
        raise InputError(f"{prefix}{file}: missing (listed in summary.json)") from None
    arr = decode_array(desc, data, name=prefix + file)
    if "sentinel" in desc:
        return decode_ids(arr, int(desc["sentinel"]))
    return arr


def _relevance(store: Store, prefix: str, summary: dict[str, Any]) -> np.ndarray | None:
    """The optional relevance table (format 1.1); None for 1.0 results, which lack it."""
    rel = _array(store, prefix, summary, "relevance", RELEVANCE_KEY)
    return None if rel is None else rel.astype(np.float32, copy=False)


def _frames(summary: dict[str, Any], prefix: str) -> tuple[np.ndarray | None, np.ndarray | None, str]:
    """(splat -> capture 4x4 or None, capture -> world 4x4 or None, layout) from the optional
    `frames` block (format 1.2; `capture_to_world` since 1.4)."""
    frames = summary.get("frames")
    if frames is None:
        return None, None, ""
    if not isinstance(frames, dict):
        raise InputError(f"{prefix}{SUMMARY_KEY}: frames must be an object")
    layout = str(frames.get("layout", ""))
    return _matrix(frames, "splat_to_capture", prefix), _matrix(frames, "capture_to_world", prefix), layout


def _matrix(frames: dict[str, Any], name: str, prefix: str) -> np.ndarray | None:
    matrix = frames.get(name)
    if matrix is None:
        return None
    try:
        m = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        m = np.zeros(0)
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise InputError(f"{prefix}{SUMMARY_KEY}: frames.{name} must be a finite 4x4 matrix")
    return m


def result_location(folder: Path) -> tuple[Path, str]:
    """(folder, prefix) of a result folder itself (prefix '') or of a run folder with `result/`
    inside; an InputError naming the folder when it holds neither."""
    if (folder / SUMMARY_KEY).is_file():
        return folder, ""
    if (folder / RESULT_PREFIX / SUMMARY_KEY).is_file():
        return folder, RESULT_PREFIX
    if not folder.is_dir():
        raise InputError("no such folder; give a run folder of `bfields run --out`", source=str(folder))
    raise InputError(
        f"no result here (neither {SUMMARY_KEY} nor {RESULT_PREFIX}{SUMMARY_KEY})", source=str(folder)
    )


def _folder_source(folder: Path, prefix: str | None) -> tuple[Store, str]:
    """A folder as (store, prefix): a result folder itself, or a folder with `result/` inside."""
    if prefix is not None:
        return LocalStore(folder), prefix
    root, found = result_location(folder)
    return LocalStore(root), found


def read_result(source: Store | str | Path, prefix: str | None = None) -> Result:
    """The `Result` stored under `prefix` (ids as int64 with -1 = none, probabilities float32).

    `source` is a `Store` (then `prefix` defaults to the pipeline's `result/`) or a plain folder:
    a run's output folder (`read_result("out/demo")`) or the result folder inside it."""
    if isinstance(source, str | Path):
        source, prefix = _folder_source(Path(source), prefix)
    store = source
    prefix = normalise_prefix(RESULT_PREFIX if prefix is None else prefix)
    summary = read_summary(store, prefix)
    object_ids = _array(store, prefix, summary, "object_ids", OBJECT_IDS_KEY)
    probabilities = _array(store, prefix, summary, "probabilities", PROBABILITIES_KEY)
    if object_ids is None or probabilities is None:
        raise InputError(f"{prefix}{SUMMARY_KEY}: object_ids and probabilities are required")
    try:
        tasks = [str(t) for t in summary["tasks"]]
        selections = {
            str(entry["task"]): [SelectedObject.from_dict(o) for o in entry["objects"]]
            for entry in summary["selections"]
        }
        not_found = {
            str(entry["task"]): NotFound.from_dict(entry["not_found"])
            for entry in summary["selections"]
            if entry.get("not_found") is not None
        }
    except (KeyError, TypeError) as exc:
        raise InputError(f"{prefix}{SUMMARY_KEY}: malformed tasks or selections ({exc!r})") from None
    splat_to_capture, capture_to_world, layout = _frames(summary, prefix)
    splat_digest, keys = _keys(summary, prefix)
    scene_scale = summary.get("scene_scale")
    if scene_scale is not None and not isinstance(scene_scale, dict):
        raise InputError(f"{prefix}{SUMMARY_KEY}: scene_scale must be an object")
    result = Result(
        tasks=tasks,
        object_ids=object_ids,
        probabilities=probabilities.astype(np.float32, copy=False),
        selections=selections,
        primitive_ids=_array(store, prefix, summary, "primitive_ids", PRIMITIVE_IDS_KEY),
        relevance=_relevance(store, prefix, summary),
        parameters=summary.get("parameters", {}),
        models=summary.get("models", {}),
        timings_s=summary.get("timings_s", {}),
        num_primitives=summary.get("counts", {}).get("primitives"),
        splat_to_capture=splat_to_capture,
        layout=layout,
        not_found=not_found,
        capture_to_world=capture_to_world,
        scene_scale=scene_scale,
        ranked_by=str(summary.get("ranked_by", "")),
        splat_digest=splat_digest,
        keys=keys,
        format_version=str(summary["format_version"]),
    )
    result.validate()
    computed = result.content_keys()  # results older than 1.5 carry none: computed here
    for objs in result.selections.values():
        for obj in objs:
            if obj.key is None:
                obj.key = computed[obj.object_id]
    return result


def _keys(summary: dict[str, Any], prefix: str) -> tuple[str, list[str] | None]:
    """(splat digest, object keys or None) of a 1.5 result; ('', None) before 1.5."""
    digest, keys = summary.get("splat_digest") or "", summary.get("object_keys")
    if not isinstance(digest, str):
        raise InputError(f"{prefix}{SUMMARY_KEY}: splat_digest must be a string")
    if keys is not None and not (isinstance(keys, list) and all(isinstance(k, str) for k in keys)):
        raise InputError(f"{prefix}{SUMMARY_KEY}: object_keys must be a list of strings")
    return digest, keys


def object_gaussians(result: Result, gaussians: Gaussians, object_id: int) -> Gaussians:
    """The Gaussians of one object (after floater removal), every attribute kept."""
    if len(gaussians) != result.num_gaussians:
        raise InputError(
            f"the splat has {len(gaussians)} Gaussians but the result has {result.num_gaussians}"
        )
    return gaussians.subset(np.asarray(result.object_ids) == object_id)


def result_sizes(store: Store, prefix: str) -> dict[str, int]:
    """Bytes of every file of the result under `prefix`, keyed relative to the prefix, plus totals:
    `total/object_map` (object ids + probabilities + relevance + summary: the map a consumer needs, the paper's
    "Objects" column), `total/with_primitives` (plus the optional primitive ids) and
    `total/exports` (the .ply files)."""
    prefix = normalise_prefix(prefix)
    sizes = {key[len(prefix) :]: store.size(key) for key in store.list(prefix)}
    if SUMMARY_KEY not in sizes:
        raise InputError(f"{prefix}{SUMMARY_KEY}: no result here")
    object_map = sum(sizes.get(k, 0) for k in (SUMMARY_KEY, OBJECT_IDS_KEY, PROBABILITIES_KEY, RELEVANCE_KEY))
    totals = {
        "total/object_map": object_map,
        "total/with_primitives": object_map + sizes.get(PRIMITIVE_IDS_KEY, 0),
        "total/exports": sum(v for k, v in sizes.items() if k.startswith("exports/")),
    }
    return {**sizes, **totals}
