"""Runs the stages of the stage table (`stage_table.STAGE_TABLE`) in process, resuming finished ones.

The same `run_stage` is what a Celery task calls; the CLI calls `run_job`. A stage whose marker
exists is skipped, which is what makes a redelivered or retried task resume from the last
finished stage. A stage function is called with the job's three parts, ``run(spec, scene,
runner)`` (`factories.Job`), whichever program built the job.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from functools import partial
from typing import Any

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.artifacts import RESULT_PREFIX
from bayesian_fields_core.job.factories import Job
from bayesian_fields_core.job.job_scene import JobScene
from bayesian_fields_core.job.markers import MARKER_DIR, is_done, marker_key, read_marker
from bayesian_fields_core.job.stage_table import STAGES, stage
from bayesian_fields_core.job.store import Store
from bayesian_fields_core.params import PipelineParams

log = logging.getLogger(__name__)


def run_stage(name: str, job: Job, *, force: bool = False) -> dict[str, Any]:
    """Run one stage unless its marker says it already finished; returns the stage report.

    The cancel check runs at the stage boundary, before the stage starts (the stages check again
    inside their loops), so a job cancelled between two stages never starts the next."""
    row = stage(name)
    if not force and is_done(job.spec, name):
        log.info("stage %s already finished for %s; skipping", name, job.spec.job_prefix or "<root>")
        job.runner.progress(name, 1.0)
        return read_marker(job.spec, name)
    job.runner.check_cancel()
    # The stage's clock starts here, before anything it does (model loading included): the CLI's
    # bar starts on this call, so the bar and the stage report time the same span.
    job.runner.progress(name, 0.0)
    start = time.perf_counter()
    report = row.load()(job.spec, job.scene, job.runner)
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


def run_job(
    job: Job, *, force: bool = False, around: StageWrapper | None = None
) -> dict[str, dict[str, Any]]:
    """Run every stage in order; returns {stage: report}. `around(name, run)`, when given, runs
    each stage's `run()` and returns its report (`bfields run --trace` times each stage in a span).

    The calibration is checked against the encoder first (from files, nothing is loaded), so a
    calibration made for another CLIP fails in a second, not after the whole perception stage.
    """
    _ = job.runner.models.calibration
    check_inputs(job.spec.params, job.scene)
    if force:  # a rerun that fails part-way must not leave the previous run's later markers
        for name in STAGES:
            job.spec.store.delete(marker_key(job.spec, name))
    wrap = around or _plain
    return {name: wrap(name, partial(run_stage, name, job, force=force)) for name in STAGES}


StageWrapper = Callable[[str, Callable[[], dict[str, Any]]], dict[str, Any]]
"""`run_job`'s `around`: given a stage's name and the call that runs it, returns its report."""


def _plain(name: str, run: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    return run()


def check_inputs(params: PipelineParams, scene: JobScene) -> None:
    """Input problems the parameters imply, found before any stage starts (not after the
    perception stage, minutes in): `depth_source='input'` needs a depth map on every frame."""
    if params.depth_source == "input":
        missing = [frame.name for _, frame in scene.selected_frames if frame.depth_path is None]
        if missing:
            raise InputError(
                f"depth_source='input' but {len(missing)} frame(s) have no depth map "
                f"(first: {missing[0]}); give depth maps or use depth_source=median",
                source="parameters.depth_source",
            )
