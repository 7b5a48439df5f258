"""Runs the stages of the stage table (`stage_table.STAGE_TABLE`) in process, resuming finished ones.

The same `run_stage` is what a Celery task calls; the CLI calls `run_job`. A stage whose marker
exists is skipped, which is what makes a redelivered or retried task resume from the last
finished stage.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.artifacts import RESULT_PREFIX
from bayesian_fields_core.job.context import JobContext, Models
from bayesian_fields_core.job.markers import MARKER_DIR, is_done, marker_key, read_marker
from bayesian_fields_core.job.stage_table import STAGES, stage
from bayesian_fields_core.job.store import Store

log = logging.getLogger(__name__)


def run_stage(name: str, ctx: JobContext, *, force: bool = False) -> dict[str, Any]:
    """Run one stage unless its marker says it already finished; returns the stage report.

    The cancel check runs at the stage boundary, before the stage starts (the stages check again
    inside their loops), so a job cancelled between two stages never starts the next."""
    spec = stage(name)
    if not force and is_done(ctx, name):
        log.info("stage %s already finished for %s; skipping", name, ctx.job_prefix or "<root>")
        ctx.progress(name, 1.0)
        return read_marker(ctx, name)
    ctx.check_cancel()
    # The stage's clock starts here, before anything it does (model loading included): the CLI's
    # bar starts on this call, so the bar and the stage report time the same span.
    ctx.progress(name, 0.0)
    start = time.perf_counter()
    report = spec.load()(ctx)
    log.debug("stage %s: %.2f s%s", name, time.perf_counter() - start, _step_timings(report))
    return report


def discard_result(store: Store, job_prefix: str) -> None:
    """Remove a job's result and its last stage's marker: a cancelled job keeps no result, even
    when the cancel was accepted after the result was written but before the job was marked done."""
    store.delete_prefix(job_prefix + RESULT_PREFIX)
    store.delete(job_prefix + f"{MARKER_DIR}{STAGES[-1]}.json")


def _step_timings(report: dict[str, Any]) -> str:
    """`` (segment 1.2 s, embed 3.4 s)`` from a stage report's ``*_seconds`` and ``timings``."""
    steps = {k.removesuffix("_seconds"): v for k, v in report.items() if k.endswith("_seconds")}
    steps.update(report.get("timings") or {})
    parts = [f"{k} {v:.2f} s" for k, v in steps.items() if isinstance(v, int | float)]
    return f" ({', '.join(parts)})" if parts else ""


def run_job(ctx: JobContext, *, force: bool = False) -> dict[str, dict[str, Any]]:
    """Run every stage in order; returns {stage: report}.

    The calibration is checked against the encoder first (from files, nothing is loaded), so a
    calibration made for another CLIP fails in a second, not after the whole perception stage.
    """
    _ = ctx.models.calibration
    check_inputs(ctx)
    if force:  # a rerun that fails part-way must not leave the previous run's later markers
        for name in STAGES:
            ctx.store.delete(marker_key(ctx, name))
    return {name: run_stage(name, ctx, force=force) for name in STAGES}


def check_inputs(ctx: JobContext) -> None:
    """Input problems the parameters imply, found before any stage starts (not after the
    perception stage, minutes in): `depth_source='input'` needs a depth map on every frame."""
    if ctx.params.depth_source == "input":
        missing = [frame.name for _, frame in ctx.selected_frames() if frame.depth_path is None]
        if missing:
            raise InputError(
                f"depth_source='input' but {len(missing)} frame(s) have no depth map "
                f"(first: {missing[0]}); give depth maps or use depth_source=median",
                source="parameters.depth_source",
            )


def load_models(profile: Any = None, *, device: str | None = None) -> Models:
    """Models of a model profile (path, dict or `ModelProfile`); built lazily on first use.

    None selects the bundled default profile (classical segmenter + the project's tiny CLIP).
    `device` overrides the profile's per-model devices; None keeps them.
    """
    from bayesian_fields_core.perception import profiles as registry

    if profile is None:
        prof = registry.default_profile()
    elif isinstance(profile, str | Path | dict):
        prof = registry.load_profile(profile)
    else:
        prof = profile
    return Models(prof, device=device)
