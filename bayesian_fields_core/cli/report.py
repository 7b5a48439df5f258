"""Human-readable output of a finished run: per task, the chosen objects; then stage timings."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from rich.console import Console, JustifyMethod
from rich.table import Table

from bayesian_fields_core.results.format import Result, SelectedObject


def _files(out: Path) -> dict[str, Any]:
    """Preview and export paths recorded in the result's summary.json (absent keys: none)."""
    try:
        summary = json.loads((out / "result" / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    root = out / "result"
    previews = summary.get("previews") or {}
    exports = summary.get("exports") or {}
    return {
        "previews": {p["task"]: str(root / p["file"]) for p in previews.get("tasks", [])},
        "contact_sheet": str(root / previews["contact_sheet"]) if previews.get("contact_sheet") else None,
        "task_exports": {t: str(root / k) for t, k in (exports.get("tasks") or {}).items()},
        "object_exports": {int(i): str(root / k) for i, k in (exports.get("objects") or {}).items()},
        "scene_export": str(root / exports["scene"]) if exports.get("scene") else None,
    }


SCORE_LABELS = {
    "evidence": "evidence",
    "relevance": "p(relevant)",
    "conditional": "p(task|object)",
}
"""Column header of the score each `selection_score` ranks by (`SelectedObject.score`)."""

SCORE_MEANINGS = {
    "evidence": (
        "mean log-odds that the object's Gaussians are relevant; p(relevant), their mean probability, "
        "saturates near 1 and need not follow the ranks"
    ),
    "relevance": "mean probability that the object's Gaussians are relevant",
    "conditional": "p(task | object), normalised over the tasks and the null task",
}


def units(result: Result) -> str:
    """How lengths of `result` are named: 'm' only for a capture declared metric, else 'scene
    units' (COLMAP's units are arbitrary; older results say nothing, so they get 'scene units')."""
    return str((result.scene_scale or {}).get("units") or "scene units")


def ranking_caption(result: Result) -> str:
    """What orders the ranks and which objects are listed, in words (printed under the table)."""
    name = result.ranked_by or "relevance"
    threshold = result.parameters.get("prune_threshold")
    listed = (
        ""
        if threshold is None
        else f" Objects with p(relevant) < {threshold:g} for a task are not its answers."
    )
    return f"Ranked by {SCORE_LABELS.get(name, name)}: {SCORE_MEANINGS.get(name, name)}.{listed}"


def _ranked_value(obj: SelectedObject) -> float:
    """The number a task's ranks follow: the recorded score (1.4), else the probability."""
    return float(obj.probability if obj.score is None else obj.score)


def result_summary(result: Result, reports: dict[str, dict[str, Any]], out: Path) -> dict[str, Any]:
    """A JSON-able digest of a run for `--json` and scripts: per task its ranked objects (with
    oriented box and export path), the preview image and the task's recoloured splat."""
    files = _files(out)
    objects_ply = files.get("object_exports", {})
    return {
        "output": str(out),
        "tasks": {
            task: [
                {
                    "object_id": o.object_id,
                    "key": o.key,
                    "score": round(_ranked_value(o), 4),
                    "probability": round(o.probability, 4),
                    "num_gaussians": o.num_gaussians,
                    "centroid": [round(float(c), 4) for c in o.centroid],
                    **(
                        {"capture_centroid": [round(float(c), 4) for c in o.capture_centroid]}
                        if o.capture_centroid is not None
                        else {}
                    ),
                    **(
                        {"world_centroid": [round(float(c), 4) for c in o.world_centroid]}
                        if o.world_centroid is not None
                        else {}
                    ),
                    "box": o.box.to_dict(),
                    "export": objects_ply.get(o.object_id),
                }
                for o in objects
            ]
            for task, objects in result.selections.items()
        },
        "not_found": {task: nf.to_dict() for task, nf in result.not_found.items()},
        "ranked_by": result.ranked_by or "relevance",
        "scene_scale": result.scene_scale,
        "previews": files.get("previews", {}),
        "contact_sheet": files.get("contact_sheet"),
        "task_exports": files.get("task_exports", {}),
        "scene_export": files.get("scene_export"),
        "counts": result.counts(),
        "frames": {
            "layout": result.layout,
            "splat_to_capture": None if result.splat_to_capture is None else result.splat_to_capture.tolist(),
            "capture_to_world": None if result.capture_to_world is None else result.capture_to_world.tolist(),
            "centroids": "splat file frame"
            + ("; capture_centroid: cameras' frame" if result.splat_to_capture is not None else "")
            + (
                "; world_centroid: the data's world (COLMAP) frame"
                if result.capture_to_world is not None
                else ""
            ),
            "units": units(result),
        },
        "stage_seconds": {name: round(float(r.get("seconds", 0.0)), 3) for name, r in reports.items()},
    }


def answer_table(result: Result) -> Table:
    """Each task's answers, best first. The first number is the score the ranks follow
    (`ranking_caption` says what it is), so rank order is the order of that column; p(relevant) is shown beside it
    when it is a different number. Centroids are in the splat file's frame, in scene units unless
    the capture is declared metric."""
    name = result.ranked_by or "relevance"
    label = SCORE_LABELS.get(name, name)
    with_p = label != "p(relevant)"
    table = Table(title="Task-relevant objects", show_lines=False)
    columns: list[tuple[str, JustifyMethod]] = [
        ("task", "left"),
        ("rank", "right"),
        ("object", "right"),
        (f"{label} (ranks)", "right"),
    ]
    columns += [("p(relevant)", "right")] if with_p else []
    columns += [("Gaussians", "right"), (f"centroid ({units(result)})", "left")]
    for column, justify in columns:
        table.add_column(column, justify=justify)
    for task, objects in result.selections.items():
        if not objects:
            missing = result.not_found.get(task)
            reason = f"not found: {missing.reason}" if missing else "no object"
            table.add_row(task, *["-"] * (len(columns) - 2), reason)
        for rank, obj in enumerate(objects, start=1):
            score = _ranked_value(obj)
            row = [task if rank == 1 else "", str(rank), str(obj.object_id)]
            row += [f"{score:+.2f}" if name == "evidence" and obj.score is not None else f"{score:.3f}"]
            row += [f"{obj.probability:.3f}"] if with_p else []
            row += [str(obj.num_gaussians), "(" + ", ".join(f"{c:+.2f}" for c in obj.centroid) + ")"]
            table.add_row(*row)
    return table


def print_result(
    result: Result, reports: dict[str, dict[str, Any]], out: Path, *, json_output: bool = False
) -> None:
    if json_output:
        print(json.dumps(result_summary(result, reports, out), indent=2))
        return
    console = Console()
    console.print(answer_table(result))
    console.print(ranking_caption(result), soft_wrap=True)
    scale = result.scene_scale or {}
    if scale.get("value") is not None:
        lengths = scale.get("lengths") or {}
        how = ": ".join(str(part) for part in (scale.get("source"), scale.get("definition")) if part)
        console.print(
            f"scene scale {float(scale['value']):.4g} {units(result)} ({how}); "
            f"depth tolerance {float(lengths.get('depth_tolerance', 0)):.4g}",
            soft_wrap=True,
        )
    if result.splat_to_capture is not None:
        console.print(
            f"centroids are in the splat file's frame ({result.layout} layout: the splat was mapped into the "
            "cameras' frame for the run); --json also gives capture_centroid, summary.json capture_frame boxes"
        )
    counts = result.counts()
    timing = ", ".join(f"{name} {float(r.get('seconds', 0.0)):.1f}s" for name, r in reports.items())
    perceive = reports.get("perceive", {})
    console.print(
        f"{counts.get('gaussians')} Gaussians, {counts.get('primitives')} primitives, "
        f"{counts.get('objects')} objects | {timing} | "
        f"perception: {perceive.get('frames_computed', 0)} frames computed, "
        f"{perceive.get('frames_cached', 0)} from cache"
    )
    console.print(f"result written to {out / 'result'}")
    files = _files(out)
    if files.get("contact_sheet"):
        console.print(f"previews: {files['contact_sheet']} (all tasks)")
        for task, path in files["previews"].items():
            console.print(f"  {task}: {path}")
    if files.get("task_exports"):
        console.print(f"per-task splats: {Path(next(iter(files['task_exports'].values()))).parent}/")
    console.print(f"look at it: bfields view {out}")
