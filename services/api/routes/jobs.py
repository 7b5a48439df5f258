"""Job routes: submit (idempotent), status, result links, cancel, list; plus batches of jobs
(submit, status, page, cancel, retry).

HTTP only: each route turns its request into a call of the jobs domain (`jobs.service`: the rules
of submission, idempotency, admission, cancel and retry) and its answer into a response schema;
the domain's refusals become their statuses in `api.edge`."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import PurePosixPath
from typing import Annotated, Any

from fastapi import APIRouter, Header, HTTPException, Query, Request, Response, status
from fastapi.concurrency import run_in_threadpool
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, StreamingResponse

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import ArtifactNotFound, get_json, validate_key
from bayesian_fields_service.api.json_body import openapi_body, parse_body
from bayesian_fields_service.api.query import PAGE_LIMIT, JobCursor, PositionCursor, SceneFilter
from bayesian_fields_service.api.ratelimit import quota_headers
from bayesian_fields_service.api.result_zip import zip_stream
from bayesian_fields_service.api.schemas import (
    Artifact,
    BatchJob,
    BatchRequest,
    BatchStatus,
    JobAccepted,
    JobList,
    JobRequest,
    JobResult,
    Problem,
)
from bayesian_fields_service.api.state import BODY_ERRORS, ERRORS, AppState, State, Tenant, not_found
from bayesian_fields_service.jobs.batches import BatchRecord, batch_progress, progress_of_jobs
from bayesian_fields_service.jobs.model import JobRecord, JobState
from bayesian_fields_service.jobs.service import BatchAsk, body_digest
from bayesian_fields_service.jobs.validation import JobAsk

router = APIRouter(prefix="/v1", tags=["jobs"])

#: The quota headers a submission's answer carries where it stored jobs (`api.ratelimit`).
QUOTA_HEADERS: dict[str, Any] = {
    "RateLimit-Policy": {
        "schema": {"type": "string"},
        "description": 'The tenant\'s job quota: `"jobs";q=<unfinished jobs allowed>` (IETF httpapi draft)',
    },
    "RateLimit": {
        "schema": {"type": "string"},
        "description": 'What is left of it after this request: `"jobs";r=<jobs>` (`;t=<s>` on a 429)',
    },
}


@router.post(
    "/jobs",
    status_code=status.HTTP_202_ACCEPTED,
    response_model=JobAccepted,
    summary="Submit a job",
    responses={
        **BODY_ERRORS,
        200: {
            "model": JobAccepted,
            "description": "The earlier job of this Idempotency-Key (created: false)",
        },
        202: {"description": "The new job", "headers": QUOTA_HEADERS},
        409: {"model": Problem, "description": "The scene is not ready"},
        429: {
            "model": Problem,
            "description": "The tenant's waiting bound is full; see Retry-After",
            "headers": QUOTA_HEADERS,
        },
    },
)
def submit_job(
    body: JobRequest,
    tenant: Tenant,
    state: State,
    response: Response,
    idempotency_key: Annotated[
        str | None,
        Header(
            max_length=200,
            description="Retries with the same key return the first job instead of a new one "
            "(printable ASCII, at most 200 characters).",
        ),
    ] = None,
) -> JobAccepted:
    ask = JobAsk(body.scene_id, body.tasks, body.parameters, body.model_profile, body.priority,
                 body.callback_url, idempotency_key or None)  # fmt: skip
    submitted = state.service.submit_job(tenant, ask)
    if not submitted.created:
        response.status_code = status.HTTP_200_OK
    if submitted.quota is not None:
        response.headers.update(quota_headers(submitted.quota))
    record = submitted.record
    return JobAccepted(id=record.id, state=record.state, created=submitted.created)


@router.get(
    "/jobs/{job_id}",
    response_model=JobRecord,
    summary="Job state, stage, progress, timings",
    responses=ERRORS,
)
def get_job(job_id: str, tenant: Tenant, state: State) -> JobRecord:
    return state.service.with_queue_position(state.service.job(tenant, job_id))


@router.get("/jobs", response_model=JobList, summary="List jobs, newest first", responses=ERRORS)
def list_jobs(
    tenant: Tenant,
    state: State,
    job_state: Annotated[JobState | None, Query(alias="state")] = None,
    scene_id: SceneFilter = None,
    limit: Annotated[int, Query(ge=1, le=PAGE_LIMIT)] = 50,
    cursor: JobCursor = None,
) -> JobList:
    items, next_cursor = state.jobs.list(
        tenant, state=job_state, scene_id=scene_id, limit=limit, cursor=cursor
    )
    return JobList(items=items, next_cursor=next_cursor)


@router.get(
    "/jobs/{job_id}/result",
    response_model=JobResult,
    summary="Result summary and download links of every artifact",
    responses={**ERRORS, 409: {"model": Problem}},
)
def get_result(job_id: str, tenant: Tenant, state: State) -> JobResult:
    record = _succeeded(state, tenant, job_id)
    ts = state.tenant(tenant)
    prefix = f"{record.job_prefix}result/"
    try:
        summary = get_json(ts, prefix + "summary.json")
    except ArtifactNotFound:
        summary = {}
    artifacts = []
    transfers = state.transfers(tenant)
    for key in ts.list(prefix):
        rel = key[len(record.job_prefix) :]
        if transfers is not None:
            url = transfers.link(key, filename=PurePosixPath(key).name)
        else:
            url = f"/v1/jobs/{job_id}/artifacts/{rel}"
        artifacts.append(Artifact(path=rel, size=ts.size(key), url=url))
    return JobResult(id=job_id, state=record.state, summary=summary, artifacts=artifacts,
                     expires_in_s=state.settings.presign_expiry_s)  # fmt: skip


def _succeeded(state: AppState, tenant: str, job_id: str) -> JobRecord:
    """The tenant's job (404 otherwise), once it has succeeded (409 naming its state otherwise)."""
    record = state.service.job(tenant, job_id)
    if record.state != JobState.succeeded:
        raise HTTPException(
            status.HTTP_409_CONFLICT, f"job {job_id!r} is {record.state.value}, not succeeded"
        )
    return record


@router.get(
    "/jobs/{job_id}/result.zip",
    response_class=StreamingResponse,
    summary="Every file of a finished job's result as one zip, streamed (the /ui 'download all')",
    responses={**ERRORS, 409: {"model": Problem}, 200: {"content": {"application/zip": {}}}},
)
def get_result_zip(job_id: str, tenant: Tenant, state: State) -> StreamingResponse:
    record = _succeeded(state, tenant, job_id)
    ts = state.tenant(tenant)
    members = [(key, key[len(record.job_prefix) :]) for key in ts.list(f"{record.job_prefix}result/")]
    return StreamingResponse(
        zip_stream(ts, members),
        media_type="application/zip",
        headers={"Content-Disposition": f'attachment; filename="{job_id}.zip"'},
    )


@router.get(
    "/jobs/{job_id}/artifacts/{path:path}",
    response_class=FileResponse,
    summary="Download one artifact (only for storage backends that cannot presign)",
    responses=ERRORS,
)
def get_artifact(job_id: str, path: str, tenant: Tenant, state: State) -> FileResponse:
    record = state.service.job(tenant, job_id)
    try:
        key = record.job_prefix + validate_key(path)
    except InputError:
        raise not_found("artifact", path) from None
    file = state.jobs.local_file(tenant, key) if path.startswith("result/") else None
    if file is None or not file.is_file():
        raise not_found("artifact", path)
    return FileResponse(file, filename=file.name)


@router.delete(
    "/jobs/{job_id}",
    response_model=JobRecord,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Cancel a job (a running stage stops at its next frame)",
    responses=ERRORS,
)
def cancel_job(job_id: str, tenant: Tenant, state: State) -> JobRecord:
    return state.service.cancel_job(tenant, job_id)


_BATCH_ERRORS: dict[int | str, dict[str, Any]] = {
    **BODY_ERRORS,
    200: {"model": BatchStatus, "description": "The earlier batch of this Idempotency-Key (created: 0)"},
    202: {"description": "The new batch", "headers": QUOTA_HEADERS},
    409: {"model": Problem, "description": "A scene is not ready"},
    429: {
        "model": Problem,
        "description": "Past the tenant's waiting bound; see Retry-After",
        "headers": QUOTA_HEADERS,
    },
}


@router.post(
    "/batches",
    status_code=status.HTTP_202_ACCEPTED,
    response_model=BatchStatus,
    summary="Submit many jobs at once (items, or scenes x task lists)",
    tags=["batches"],
    responses=_BATCH_ERRORS,
    openapi_extra=openapi_body(BatchRequest),
)
async def submit_batch(
    request: Request,
    tenant: Tenant,
    state: State,
    idempotency_key: Annotated[
        str | None,
        Header(
            max_length=200,
            description="Retries with the same key return the first batch instead of a new one.",
        ),
    ] = None,
) -> Response:
    """The body is read here; the bulk lane's child process serves the rest (bulk_lane.py), or,
    with the lane off (and in the child), a worker thread: a fleet-sized batch must not hold the
    event loop (json_body.py says why)."""
    raw = await request.body()
    if state.bulk_lane is not None:  # served by this process's child (bulk_lane.py says why)
        return await state.bulk_lane.forward(request, raw)
    return await run_in_threadpool(_submit_batch, state, tenant, raw, idempotency_key)


def _submit_batch(state: AppState, tenant: str, raw: bytes, idempotency_key: str | None) -> Response:
    body = parse_body(BatchRequest, raw)

    def item(scene_id: str, tasks: list[str], key: str | None = None) -> JobAsk:
        return JobAsk(
            scene_id, tasks, body.parameters, body.model_profile, body.priority, idempotency_key=key
        )

    items = [item(i.scene_id, i.tasks, i.idempotency_key) for i in body.items]
    items += [item(s, t) for s in body.scene_ids for t in body.task_lists]
    ask = BatchAsk(items, body.priority, body.callback_url,
                   body_digest(body.model_dump_json()) if idempotency_key else "")  # fmt: skip
    submitted = state.service.submit_batch(tenant, ask, idempotency_key or None)
    if not submitted.jobs:  # the earlier batch of this Idempotency-Key
        answer, code = _batch_status(state, submitted.batch, created=0), status.HTTP_200_OK
    else:
        answer = _status_of(submitted.batch, submitted.jobs, created=submitted.created)
        code = status.HTTP_202_ACCEPTED
    headers = quota_headers(submitted.quota) if submitted.quota is not None else None
    return Response(
        answer.model_dump_json(), status_code=code, media_type="application/json", headers=headers
    )


def _status_of(batch: BatchRecord, jobs: Sequence[JobRecord | None], *, created: int = 0,
               with_jobs: bool = True) -> BatchStatus:  # fmt: skip
    """A batch's status from its jobs' records (when the answer lists them anyway)."""
    present = [j for j in jobs if j is not None]
    now = progress_of_jobs((j.state.value, j.progress) for j in present)
    return BatchStatus(
        id=batch.id, created_at=batch.created_at or datetime.now(UTC), progress=now.progress,
        counts=now.counts, finished=now.finished, total=batch.total, created=created,
        jobs=[BatchJob(id=j.id, scene_id=j.scene_id, tasks=j.tasks, state=j.state, stage=j.stage,
                       progress=j.progress, error=j.error) for j in present] if with_jobs else [],
    )  # fmt: skip


def counted_status(state: AppState, batch: BatchRecord, *, created: int = 0) -> BatchStatus:
    """A batch's status from its row's counts (kept by the records) and its dispatched jobs' live
    progress: a few reads whatever the batch's size."""
    live = state.jobs.live_batch(batch)
    now = batch_progress(live.counts, live.active_progress, live.total)
    return BatchStatus(
        id=batch.id, created_at=batch.created_at or datetime.now(UTC), progress=now.progress,
        counts=now.counts, finished=now.finished, total=live.total, created=created, jobs=[],
    )  # fmt: skip


def _batch_status(
    state: AppState, batch: BatchRecord, *, created: int = 0, with_jobs: bool = True
) -> BatchStatus:
    if not with_jobs:
        return counted_status(state, batch, created=created)
    return _status_of(batch, [j for _, j in state.jobs.batch_jobs(batch)], created=created)


@router.get(
    "/batches/{batch_id}",
    response_model=BatchStatus,
    summary="Aggregated progress of a batch (its job list with jobs=true, for small batches)",
    tags=["batches"],
    responses={
        **ERRORS,
        422: {
            "model": Problem,
            "description": "jobs=true on a batch larger than BFIELDS_BATCH_JOBS_INLINE_MAX",
        },
    },
)
def get_batch(
    batch_id: str,
    tenant: Tenant,
    state: State,
    jobs: Annotated[
        bool,
        Query(
            description="true: list every job in the answer too, for a batch of at most "
            "BFIELDS_BATCH_JOBS_INLINE_MAX jobs (default 1,000; a larger one is refused with 422). "
            "Page through any batch's jobs with GET /v1/batches/{id}/jobs."
        ),
    ] = False,
) -> BatchStatus:
    """Counts and progress by default: a few reads whatever the batch's size, so one tenant
    polling a fleet-sized batch cannot slow the others (a 20,000-job list was 3.6 MB and ~52 s)."""
    batch = state.service.batch(tenant, batch_id)
    bound = state.settings.batch_jobs_inline_max
    if jobs and batch.total > bound:
        msg = (
            f"jobs=true lists at most {bound} jobs (BFIELDS_BATCH_JOBS_INLINE_MAX) and this batch has "
            f"{batch.total}; leave jobs out for counts and progress, and page through its jobs with "
            f"GET /v1/batches/{batch_id}/jobs?limit={PAGE_LIMIT}&cursor=<next_cursor>"
        )
        raise RequestValidationError([{"loc": ("query", "jobs"), "msg": msg, "type": "too_many_jobs"}])
    return _batch_status(state, batch, with_jobs=jobs)


@router.get(
    "/batches/{batch_id}/jobs",
    response_model=JobList,
    summary="Page through a batch's jobs (in submission order)",
    tags=["batches"],
    responses=ERRORS,
)
def list_batch_jobs(
    batch_id: str,
    tenant: Tenant,
    state: State,
    limit: Annotated[int, Query(ge=1, le=PAGE_LIMIT)] = 100,
    cursor: PositionCursor = None,
) -> JobList:
    batch = state.service.batch(tenant, batch_id)
    rows = state.jobs.batch_jobs(batch, start=int(cursor or 0), limit=limit + 1)
    nxt = str(rows[limit][0]) if len(rows) > limit else None
    return JobList(items=[j for _, j in rows[:limit]], next_cursor=nxt)


@router.post(
    "/batches/{batch_id}/cancel",
    response_model=BatchStatus,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Cancel every unfinished job of a batch (waiting ones at once, running ones at their "
    "next frame or stage boundary)",
    tags=["batches"],
    responses=ERRORS,
)
def cancel_batch(batch_id: str, tenant: Tenant, state: State) -> BatchStatus:
    return counted_status(state, state.service.cancel_batch(tenant, batch_id))


@router.post(
    "/batches/{batch_id}/retry",
    response_model=BatchStatus,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Submit the batch's failed jobs again (as new jobs that take their place in the batch)",
    tags=["batches"],
    responses={**ERRORS, 409: {"model": Problem}, 429: {"model": Problem}},
)
def retry_batch(batch_id: str, tenant: Tenant, state: State) -> BatchStatus:
    created = state.service.retry_batch(tenant, batch_id)
    return counted_status(state, state.service.batch(tenant, batch_id), created=created)
