"""Export a result's objects as a splat other tools open: `export_objects` (and `bfields export`).

"Give me this task's objects as a file I can open": which objects (a task's answers, one rank of
them, or object ids), whose Gaussians (every attribute as in the input splat, in the splat file's
own frame, where the result's boxes are too), written by `scene.formats.write.write_splat`.

Where the Gaussians come from, first found wins: the scene folder given, the folder the result
records (`scene.folder`, local runs), else the result's own per-object `.ply` exports (a result
fetched from the service holds one per selected object, every attribute kept).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_core.results.format import Result
from bayesian_fields_core.results.reader import read_result, read_summary, result_location
from bayesian_fields_core.scene.formats.write import SUFFIXES, check_format, write_splat
from bayesian_fields_core.scene.types import Gaussians

EXPORT_DIR = "exported"
"""Folder (inside the folder given as RESULT) that exports go to when no output is named."""


@dataclass(frozen=True)
class Picked:
    """The objects one export holds: `label` names them in messages and default file names."""

    label: str
    object_ids: list[int]


def find_task(result: Result, name: str) -> str:
    """The task named `name`: its exact text, else the one task whose text contains `name`
    (case-insensitive: `--task mug`). Unknown or ambiguous names raise an InputError listing
    the tasks."""
    if name in result.tasks:
        return name
    matches = [t for t in result.tasks if name.lower() in t.lower()]
    if len(matches) == 1:
        return matches[0]
    listed = "; ".join(repr(t) for t in (matches or result.tasks))
    if matches:
        raise InputError(
            f"task {name!r} matches several tasks ({listed}); give more of its text", source="--task"
        )
    raise InputError(f"no task {name!r} in this result; its tasks: {listed}", source="--task")


def pick_objects(
    result: Result, *, task: str | None = None, rank: int | None = None, object_ids: list[int] | None = None
) -> Picked:
    """The objects to export: a task's answers (all, or the one at 1-based `rank`), or the
    objects `object_ids` (any object of the result; with `task`, each must be one of its answers)."""
    if rank is not None and object_ids:
        raise InputError("give --rank or --object, not both", source="bfields export")
    if task is None and not object_ids:
        raise InputError(
            "say what to export: --task TEXT, --object ID or --all-tasks", source="bfields export"
        )
    answers: list[int] | None = None
    label = ""
    if task is not None:
        task = find_task(result, task)
        answers = [o.object_id for o in result.selections.get(task, [])]
        label = task
        if not answers:
            missing = result.not_found.get(task)
            why = f" ({missing.reason})" if missing else ""
            raise InputError(f"task {task!r} has no answer{why}: nothing to export", source="--task")
    if object_ids:
        for object_id in object_ids:
            if not 0 <= object_id < result.num_objects:
                raise InputError(
                    f"object {object_id} is not in this result (ids 0..{result.num_objects - 1})",
                    source="--object",
                )
            if answers is not None and object_id not in answers:
                raise InputError(
                    f"object {object_id} is not an answer to {task!r} (its answers: {answers}); drop --task "
                    "to export any object",
                    source="--object",
                )
        ids = list(dict.fromkeys(object_ids))
        return Picked(f"{label} objects {'-'.join(map(str, ids))}".strip(), ids)
    assert answers is not None  # a task was given (checked above)
    if rank is None:
        return Picked(label, answers)
    if not 1 <= rank <= len(answers):
        raise InputError(f"task {task!r} has ranks 1..{len(answers)}, not {rank}", source="--rank")
    return Picked(f"{label} rank {rank}", [answers[rank - 1]])


def result_gaussians(
    folder: Path, result: Result, object_ids: list[int], scene_dir: Path | None = None
) -> tuple[Gaussians, np.ndarray]:
    """(the Gaussians of `object_ids`, the object id of each): every attribute of the input
    splat, in the splat file's frame; sources as in the module docstring."""
    root, prefix = result_location(folder)
    summary = read_summary(LocalStore(root), prefix)
    recorded = (summary.get("scene") or {}).get("folder")
    scene = scene_dir or (Path(recorded) if recorded and Path(recorded).is_dir() else None)
    ids = np.asarray(result.object_ids)
    if scene is not None:
        from bayesian_fields_core.scene.loader import load_scene

        gaussians = load_scene(scene).splat_frame_gaussians()
        if len(gaussians) != result.num_gaussians:
            raise InputError(
                f"the scene's splat has {len(gaussians)} Gaussians but the result has {result.num_gaussians}; "
                "pass --scene with the folder the run read",
                source=str(scene),
            )
        inside = np.isin(ids, object_ids)
        return gaussians.subset(inside), ids[inside]
    return _from_object_exports(root / prefix, summary, object_ids)


def _from_object_exports(
    result_dir: Path, summary: dict[str, Any], object_ids: list[int]
) -> tuple[Gaussians, np.ndarray]:
    """The objects' Gaussians from the result's per-object `.ply` exports (no scene folder)."""
    from bayesian_fields_core.scene.ply import read_ply
    from bayesian_fields_core.scene.ply_scan import concat_gaussians

    exports = (summary.get("exports") or {}).get("objects") or {}
    missing = [
        o for o in object_ids if not exports.get(str(o)) or not (result_dir / exports[str(o)]).is_file()
    ]
    if missing:
        raise InputError(
            f"no scene folder recorded or found, and objects {missing} have no .ply export in the result; "
            "pass --scene DIR (the scene folder the run read)",
            source=str(result_dir),
        )
    parts = [read_ply(result_dir / exports[str(o)]) for o in object_ids]
    owners = np.concatenate(
        [np.full(len(p), o, dtype=np.int64) for p, o in zip(parts, object_ids, strict=True)]
    )
    return concat_gaussians(parts), owners


def slug(text: str) -> str:
    """A file-name-safe form of a task or label: lowercase words joined by '-'."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")[:80] or "objects"


def export_objects(
    result_folder: str | Path,
    out: str | Path | None = None,
    *,
    task: str | None = None,
    rank: int | None = None,
    object_ids: list[int] | None = None,
    fmt: str = "ply",
    scene_dir: str | Path | None = None,
) -> Path:
    """Write the picked objects' Gaussians (`pick_objects`) of the result in `result_folder` (a
    run folder or its `result/`) to `out` as `fmt` (`scene.formats.write.EXPORT_FORMATS`);
    `out` defaults to `<result_folder>/exported/<task>.<suffix>`. Returns the file written.

    >>> export_objects("out/demo", task="mug", fmt="spz")  # doctest: +SKIP
    PosixPath('out/demo/exported/pick-up-the-orange-mug.spz')
    """
    check_format(fmt)
    folder = Path(result_folder)
    result = read_result(folder)
    picked = pick_objects(result, task=task, rank=rank, object_ids=object_ids)
    target = Path(out) if out is not None else folder / EXPORT_DIR / (slug(picked.label) + SUFFIXES[fmt])
    gaussians, _ = result_gaussians(folder, result, picked.object_ids, Path(scene_dir) if scene_dir else None)
    target.parent.mkdir(parents=True, exist_ok=True)
    return write_splat(target, gaussians, fmt)


@dataclass(frozen=True)
class TaskExports:
    """What `export_all_tasks` did: `written` {task: file} for each answered task, and
    `unanswered` {task: why} for each task with no answer, so the caller can say which tasks
    have no file instead of leaving the user to count files."""

    written: dict[str, Path]
    unanswered: dict[str, str]


def unanswered_tasks(result: Result) -> dict[str, str]:
    """{task: why it has no answer} for every task of `result` with an empty selection, in the
    result's task order; the reason is the result's "not found" reason when it recorded one."""
    out = {}
    for task in result.tasks:
        if not result.selections.get(task):
            missing = result.not_found.get(task)
            out[task] = missing.reason if missing else "no object selected"
    return out


def export_all_tasks(
    result_folder: str | Path,
    out_dir: str | Path | None = None,
    *,
    rank: int | None = None,
    fmt: str = "ply",
    scene_dir: str | Path | None = None,
) -> TaskExports:
    """One file per answered task (its answers, or its answer at `rank`) in `out_dir` (default
    `<result_folder>/exported/`), named `task_<index>_<task>.<suffix>`; tasks with no answer get
    no file and are listed with their reason. The scene is loaded once for all tasks."""
    check_format(fmt)
    folder = Path(result_folder)
    result = read_result(folder)
    target = Path(out_dir) if out_dir is not None else folder / EXPORT_DIR
    unanswered = unanswered_tasks(result)
    answered = [t for t in result.tasks if t not in unanswered]
    if not answered:
        why = "; ".join(f"{t!r}: {r}" for t, r in unanswered.items())
        raise InputError(
            f"no task of this result has an answer ({why}): nothing to export", source=str(folder)
        )
    picks = {t: pick_objects(result, task=t, rank=rank) for t in answered}
    union = sorted({o for p in picks.values() for o in p.object_ids})
    gaussians, owners = result_gaussians(folder, result, union, Path(scene_dir) if scene_dir else None)
    target.mkdir(parents=True, exist_ok=True)
    written = {}
    for index, task in enumerate(result.tasks):
        if task not in picks:
            continue
        path = target / f"task_{index:02d}_{slug(task)}{SUFFIXES[fmt]}"
        written[task] = write_splat(path, gaussians.subset(np.isin(owners, picks[task].object_ids)), fmt)
    return TaskExports(written=written, unanswered=unanswered)
