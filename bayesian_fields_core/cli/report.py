"""Human-readable output of a finished run: per task, the chosen objects; then stage timings."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from bayesian_fields_core.results.format import Result


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
                    "probability": round(o.probability, 4),
                    "num_gaussians": o.num_gaussians,
                    "centroid": [round(float(c), 4) for c in o.centroid],
                    **(
                        {"capture_centroid": [round(float(c), 4) for c in o.capture_centroid]}
                        if o.capture_centroid is not None
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
        "previews": files.get("previews", {}),
        "contact_sheet": files.get("contact_sheet"),
        "task_exports": files.get("task_exports", {}),
        "scene_export": files.get("scene_export"),
        "counts": result.counts(),
        "frames": {
            "layout": result.layout,
            "splat_to_capture": None if result.splat_to_capture is None else result.splat_to_capture.tolist(),
            "centroids": "splat file frame"
            + ("; capture_centroid: cameras' frame" if result.splat_to_capture is not None else ""),
        },
        "stage_seconds": {name: round(float(r.get("seconds", 0.0)), 3) for name, r in reports.items()},
    }


def print_result(
    result: Result, reports: dict[str, dict[str, Any]], out: Path, *, json_output: bool = False
) -> None:
    if json_output:
        print(json.dumps(result_summary(result, reports, out), indent=2))
        return
    console = Console()
    table = Table(title="Task-relevant objects", show_lines=False)
    for column, justify in (
        ("task", "left"),
        ("rank", "right"),
        ("object", "right"),
        ("p(relevant)", "right"),
        ("Gaussians", "right"),
        ("centroid (m)", "left"),
    ):
        table.add_column(column, justify=justify)
    for task, objects in result.selections.items():
        if not objects:
            missing = result.not_found.get(task)
            table.add_row(
                task, "-", "-", "-", "-", f"not found: {missing.reason}" if missing else "no object"
            )
        for rank, obj in enumerate(objects, start=1):
            table.add_row(
                task if rank == 1 else "",
                str(rank),
                str(obj.object_id),
                f"{obj.probability:.3f}",
                str(obj.num_gaussians),
                "(" + ", ".join(f"{c:+.2f}" for c in obj.centroid) + ")",
            )
    console.print(table)
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
