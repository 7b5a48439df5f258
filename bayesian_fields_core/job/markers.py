"""Stage completion markers: a stage is finished exactly when its marker exists.

Markers are written last, after every artifact of the stage, so a crash mid-stage leaves no
marker and the stage runs again (skipping the per-frame cache entries already written).
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Any

from bayesian_fields_core.job.artifacts import MARKER_DIR
from bayesian_fields_core.job.context import JobContext
from bayesian_fields_core.job.store import get_json, put_json


def marker_key(ctx: JobContext, stage: str) -> str:
    return ctx.job_key(f"{MARKER_DIR}{stage}.json")


def is_done(ctx: JobContext, stage: str) -> bool:
    return ctx.store.exists(marker_key(ctx, stage))


def read_marker(ctx: JobContext, stage: str) -> dict[str, Any]:
    return get_json(ctx.store, marker_key(ctx, stage))


def write_marker(ctx: JobContext, stage: str, report: dict[str, Any]) -> dict[str, Any]:
    finished = datetime.now(UTC)
    stamps = {"finished_at": finished.isoformat(timespec="milliseconds")}
    if isinstance(report.get("seconds"), int | float):
        started = finished - timedelta(seconds=float(report["seconds"]))
        stamps = {"started_at": started.isoformat(timespec="milliseconds"), **stamps}
    report = {"stage": stage, **stamps, **report}
    put_json(ctx.store, marker_key(ctx, stage), report)
    return report
