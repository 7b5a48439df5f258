"""``GET /v1/batches/{id}/events``: a server-sent-events stream of a batch's job states.

Why polling Redis rather than pub/sub: the stream must be right after a reconnect, a missed
message or an API restart, so each round reads the batch's job rows (one query) and the live
progress hashes of its active jobs (``bf:job:*``, one pipelined round trip; `JobStore.batch_jobs`)
and sends what changed since the last round. Events:
- ``job``: ``{"id", "state", "stage", "progress"}`` for a job whose state, stage or whole percent
  changed (every job in the first round, so a client starts from a full picture);
- ``counts``: ``{"counts": {state: n}, "total", "progress", "finished"}`` after each round with
  changes;
- ``end``: every job is terminal; the server closes the stream.
A batch larger than `batch_jobs_inline_max` (the bound of ``GET /v1/batches/{id}?jobs=true``)
gets ``counts`` and ``end`` only, read from the batch's row and its dispatched jobs (a few reads
whatever its size): re-reading 20,000 jobs every second for one watcher would slow every tenant.
A comment line keeps idle connections open. The stream closes after `events_max_s`; EventSource
clients reconnect by themselves and get a fresh full picture. Authentication is the API key
header like every route (browsers: `fetch` with the header and a stream reader, see `/ui`).
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import StreamingResponse
from starlette.concurrency import run_in_threadpool

from bayesian_fields_service.api.routes.jobs import counted_status
from bayesian_fields_service.api.state import ERRORS, AppState, State, Tenant, check_id, not_found
from bayesian_fields_service.jobs.batches import BatchRecord, progress_of_jobs
from bayesian_fields_service.jobs.model import JobState
from bayesian_fields_service.jobs.store import JobStore
from bayesian_fields_service.jobs.validation import BATCH_ID

router = APIRouter(prefix="/v1", tags=["batches"])

KEEPALIVE_S = 15.0

JobView = tuple[str, str, int]  # state, stage, whole percent


def snapshot(jobs: JobStore, batch: BatchRecord) -> dict[str, JobView]:
    """Every job's (state, stage, percent): the batch's rows in one query, live hashes of the
    active ones in one round trip (`JobStore.batch_jobs`)."""
    return {
        job.id: (
            job.state.value,
            job.stage or "",
            100 if job.state == JobState.succeeded else int(job.progress),
        )
        for _, job in jobs.batch_jobs(batch)
    }


def _event(name: str, seq: int, data: dict[str, Any]) -> str:
    return f"id: {seq}\nevent: {name}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n"


def counts_of(state: AppState, batch: BatchRecord) -> dict[str, Any]:
    """The ``counts`` event of a batch from its row (read again) and its dispatched jobs' live
    state (`jobs.counted_status`): what a large batch's stream sends, without reading its jobs."""
    now = counted_status(state, state.jobs.load_batch(batch.tenant, batch.id) or batch)
    return {"counts": now.counts, "total": now.total, "progress": now.progress, "finished": now.finished}


async def _counts_stream(request: Request, state: AppState, batch: BatchRecord) -> AsyncIterator[str]:
    """A large batch's stream: a ``counts`` event whenever they change, then ``end``."""
    seq, last = 0, None
    started = last_sent = time.monotonic()
    yield f"retry: {int(state.settings.events_poll_s * 2000)}\n\n"
    while time.monotonic() - started < state.settings.events_max_s:
        if await request.is_disconnected():
            return
        data = await run_in_threadpool(counts_of, state, batch)
        if data != last:
            last, seq = data, seq + 1
            yield _event("counts", seq, data)
            last_sent = time.monotonic()
        if data["finished"]:
            yield _event("end", seq + 1, {"batch_id": batch.id})
            return
        if time.monotonic() - last_sent > KEEPALIVE_S:
            yield ": keep-alive\n\n"
            last_sent = time.monotonic()
        await asyncio.sleep(state.settings.events_poll_s)


async def stream(request: Request, state: AppState, batch: BatchRecord) -> AsyncIterator[str]:
    if batch.total > state.settings.batch_jobs_inline_max:
        async for chunk in _counts_stream(request, state, batch):
            yield chunk
        return
    known: dict[str, JobView] = {}
    seq = 0
    started = last_sent = time.monotonic()
    yield f"retry: {int(state.settings.events_poll_s * 2000)}\n\n"
    while time.monotonic() - started < state.settings.events_max_s:
        if await request.is_disconnected():
            return
        views = await run_in_threadpool(snapshot, state.jobs, batch)
        changed = {j: v for j, v in views.items() if known.get(j) != v}
        known.update(views)
        for job_id, (job_state, stage, pct) in changed.items():
            seq += 1
            yield _event(
                "job", seq, {"id": job_id, "state": job_state, "stage": stage or None, "progress": pct}
            )
        now = progress_of_jobs((v[0], v[2]) for v in known.values())
        finished = len(known) == batch.total and now.finished
        if changed or seq == 0:
            seq += 1
            yield _event("counts", seq, {
                "counts": now.counts, "total": batch.total, "progress": now.progress, "finished": finished,
            })  # fmt: skip
            last_sent = time.monotonic()
        if finished:
            seq += 1
            yield _event("end", seq, {"batch_id": batch.id})
            return
        if time.monotonic() - last_sent > KEEPALIVE_S:
            yield ": keep-alive\n\n"
            last_sent = time.monotonic()
        await asyncio.sleep(state.settings.events_poll_s)


@router.get(
    "/batches/{batch_id}/events",
    summary="Server-sent events: per-job state changes and counts of a batch, until it finishes",
    response_class=StreamingResponse,
    responses={**ERRORS, 200: {"content": {"text/event-stream": {}}, "description": "The event stream"}},
)
async def batch_events(batch_id: str, request: Request, tenant: Tenant, state: State) -> StreamingResponse:
    check_id("batch", batch_id, BATCH_ID)
    batch = await run_in_threadpool(state.jobs.load_batch, tenant, batch_id)
    if batch is None:
        raise not_found("batch", batch_id)
    return StreamingResponse(
        stream(request, state, batch),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )
