"""Stage completion markers: a stage is finished exactly when its marker exists.

Markers are written last, after every artifact of the stage, so a crash mid-stage leaves no
marker and the stage runs again (skipping the per-frame cache entries already written). A marker
is a job artifact, so all it needs of a job is its `JobSpec` (store and prefix).
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Any

from bayesian_fields_core.job.artifacts import MARKER_DIR
from bayesian_fields_core.job.spec import JobSpec
from bayesian_fields_core.job.store import get_json, put_json


def marker_key(spec: JobSpec, stage: str) -> str:
    return spec.key(f"{MARKER_DIR}{stage}.json")


def is_done(spec: JobSpec, stage: str) -> bool:
    return spec.store.exists(marker_key(spec, stage))


def read_marker(spec: JobSpec, stage: str) -> dict[str, Any]:
    return get_json(spec.store, marker_key(spec, stage))


def write_marker(spec: JobSpec, stage: str, report: dict[str, Any]) -> dict[str, Any]:
    finished = datetime.now(UTC)
    stamps = {"finished_at": finished.isoformat(timespec="milliseconds")}
    if isinstance(report.get("seconds"), int | float):
        started = finished - timedelta(seconds=float(report["seconds"]))
        stamps = {"started_at": started.isoformat(timespec="milliseconds"), **stamps}
    report = {"stage": stage, **stamps, **report}
    put_json(spec.store, marker_key(spec, stage), report)
    return report
