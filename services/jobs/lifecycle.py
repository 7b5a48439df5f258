"""The steps of a job's life that a worker takes: start a stage, record it done, finish the job.

Each is one write through `JobStore.save` (under the row's lock, merged, terminal states sticky),
so a late worker, a duplicate delivery or a cancel racing with the last stage never turns an
ended job back or loses a field; the worker keeps only the running of the stage itself.
"""

from __future__ import annotations

from typing import Any

import redis

from bayesian_fields_core.job.stage_table import STAGES
from bayesian_fields_service.jobs import answers
from bayesian_fields_service.jobs.model import JobRecord, JobState, overall_progress, utcnow
from bayesian_fields_service.jobs.store import JobStore
from bayesian_fields_service.live.metrics import observe_job


def start_stage(jobs: JobStore, record: JobRecord, stage: str) -> JobRecord:
    """The job runs `stage` now (one more stage run); its live phase becomes 'active'. A job that
    ended meanwhile comes back terminal, and the caller stops."""
    started = jobs.save(
        record.model_copy(
            update={
                "state": JobState.running,
                "stage": stage,
                "started_at": record.started_at or utcnow(),
                "stage_runs": record.stage_runs + 1,
                "progress": overall_progress(record.stages_done, stage, 0.0),
            }
        )
    )
    if not started.state.terminal:
        jobs.set_progress(started, stage, 0.0)  # phase 'active': this worker holds the stage lock
    return started


def stage_done(
    jobs: JobStore, record: JobRecord, stage: str, report: dict[str, Any], seconds: float
) -> JobRecord:
    """Record `stage` finished with its report and time (`record` carries the stage's usage)."""
    done = [s for s in STAGES if s in {*record.stages_done, stage}]
    return jobs.save(
        record.model_copy(
            update={
                "stages_done": done,
                "timings": {**record.timings, stage: round(report.get("seconds", seconds), 3)},
                "stage_reports": {**record.stage_reports, stage: report},
                "progress": overall_progress(done, None, 0.0),
            }
        )
    )


def all_stages_done(record: JobRecord) -> bool:
    return set(record.stages_done) == set(STAGES)


def finish(jobs: JobStore, record: JobRecord, state: JobState, error: str | None = None) -> JobRecord:
    """End the job as `state`; the saved record (a cancel accepted before a success turns it into
    *cancelled*). The job-duration histogram counts the call that ended the job, once.

    A success writes the job's answers (`jobs.answers`, read from its result here, before the
    write) in the transaction that marks it succeeded: the worker, recovery and the dispatcher
    all end a job through this function, so none of them can succeed a job without its answers."""
    now = utcnow()
    update: dict[str, Any] = {"state": state, "error": error, "finished_at": now}
    if state == JobState.succeeded:
        update["progress"] = 100.0
    before = jobs.load(record.tenant, record.id)
    rows: list[dict[str, Any]] = []
    if state == JobState.succeeded and (before is None or not before.state.terminal):
        rows = answers.rows_for_finish(jobs.tenant(record.tenant), record, now)  # read before the write
    saved = jobs.save(record.model_copy(update=update), answers=rows)
    if saved.state == state and (before is None or not before.state.terminal):  # this call ended it
        start = saved.started_at or saved.created_at
        try:
            observe_job(jobs.redis, state.value, (now - start).total_seconds())
        except redis.RedisError:  # a metric, not a record
            pass
    return saved


def should_stop(jobs: JobStore, record: JobRecord) -> bool:
    """Whether a cancel was accepted (the row's flag, or the Redis flag workers poll)."""
    return record.cancel_requested or jobs.is_cancel_requested(record.tenant, record.id)
