"""Job routes: submit (idempotent), status, result links, cancel, list; plus batches of jobs."""

from __future__ import annotations

import logging
from pathlib import PurePosixPath
from typing import Annotated, Any

from fastapi import APIRouter, Header, HTTPException, Query, Response, status
from fastapi.responses import FileResponse
from pydantic import ValidationError

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import ArtifactNotFound, LocalStore, get_json, validate_key
from bayesian_fields_core.job.task_list import normalise_tasks
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_service.api.routes.callback_rules import checked_callback
from bayesian_fields_service.api.routes.scenes import _load_scene
from bayesian_fields_service.api.scene_lifecycle import scene_lock
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
from bayesian_fields_service.api.state import (
    BODY_ERRORS,
    ERRORS,
    AppState,
    State,
    Tenant,
    check_id,
    not_found,
)
from bayesian_fields_service.common.jobs import BatchRecord, JobRecord, JobState, new_id

log = logging.getLogger(__name__)
router = APIRouter(prefix="/v1", tags=["jobs"])

#: Model profiles a job may name. The workers map "default" to BFIELDS_MODEL_PROFILE.
MODEL_PROFILES = ("default",)


def _load_job(state: AppState, tenant: str, job_id: str) -> JobRecord:
    check_id("job", job_id, "j_")
    record = state.jobs.get(tenant, job_id)
    if record is None:
        raise not_found("job", job_id)
    return record


def _build_job(state: AppState, tenant: str, scene_id: str, tasks: list[str], parameters: dict[str, Any],
               model_profile: str, batch_id: str | None = None, idem: str | None = None,
               callback_url: str | None = None) -> JobRecord:  # fmt: skip
    """Validate a job request against the scene, tasks, parameters and tenant quota."""
    scene = _load_scene(state, tenant, scene_id)
    if scene.state.value != "ready":
        raise HTTPException(
            status.HTTP_409_CONFLICT, f"scene {scene_id!r} is not ready (upload not completed)"
        )
    s = state.settings
    try:
        tasks = normalise_tasks(tasks, source="tasks", max_tasks=s.max_tasks, max_chars=s.max_task_chars)
        validated = PipelineParams.model_validate(parameters)
    except InputError as exc:
        raise HTTPException(422, str(exc)) from None
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise HTTPException(422, f"parameters.{where}: {first['msg']}") from None
    _check_params_against_scene(validated, scene.summary)
    params = validated.model_dump(mode="json", exclude_unset=True)
    if model_profile not in MODEL_PROFILES:
        raise HTTPException(
            422,
            f"model_profile {model_profile!r} is unknown; available: {', '.join(MODEL_PROFILES)}",
        )
    return JobRecord(
        id=new_id("j_"), tenant=tenant, scene_id=scene_id, tasks=tasks, parameters=params,
        model_profile=model_profile, batch_id=batch_id, idempotency_key=idem,
        callback_url=checked_callback(state.settings, callback_url),
    )  # fmt: skip


def _check_params_against_scene(params: PipelineParams, summary: dict[str, Any]) -> None:
    """Refuse parameters the scene cannot satisfy now (422), instead of a job failing later."""
    frames = int(summary.get("frames", 0) or 0)
    depth_frames = int(summary.get("depth_frames", frames) or 0)  # unknown on old scenes: allow
    if params.depth_source == "input" and depth_frames < frames:
        raise HTTPException(
            422,
            f"parameters.depth_source: 'input' needs a depth map for every frame; the scene has "
            f"{depth_frames} of {frames} (use 'median' or 'expected' to render depth instead)",
        )


def _reserve_slots(state: AppState, tenant: str, records: list[JobRecord]) -> None:
    """Take one quota slot per job atomically (all or none), before anything is stored: 429 when
    they do not fit. Exact under any number of concurrent API processes (`TenantQuota`)."""
    limit = state.settings.max_active_jobs_per_tenant
    ok, active = state.jobs.quota.reserve(tenant, [r.id for r in records], limit)
    if not ok:
        raise HTTPException(
            status.HTTP_429_TOO_MANY_REQUESTS,
            f"{active} jobs are queued or running; at most {limit} are allowed per tenant "
            f"(BFIELDS_MAX_ACTIVE_JOBS_PER_TENANT); this request needs {len(records)}",
            headers={"Retry-After": str(state.settings.retry_after_s)},
        )


def _submit(state: AppState, records: list[JobRecord]) -> None:
    """Store and enqueue jobs whose slots are reserved. On any failure every job of the request
    is undone (best effort, see `JobStore.discard_unsubmitted`) and the error propagates (503),
    so a client's retry never runs the same work twice."""
    done: list[JobRecord] = []
    try:
        for record in records:
            done.append(record)
            state.jobs.create(record)
            state.enqueue(record)
    except BaseException:
        for record in done:
            state.jobs.discard_unsubmitted(record)
        try:  # the slots of the jobs never created (recovery's quota repair covers a failure here)
            state.jobs.quota.release(records[0].tenant, [r.id for r in records])
        except Exception:
            log.warning("could not release the quota slots of a failed submission; recovery will")
        raise
    for record in records:
        try:
            state.jobs.mark_enqueued(record)
        except Exception:  # enqueued: it will run; recovery drops the marker once a stage starts
            log.warning("job %s/%s enqueued but its pending marker stays", record.tenant, record.id)


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
        409: {"model": Problem, "description": "The scene is not ready"},
        429: {"model": Problem, "description": "The tenant's active-job quota is full; see Retry-After"},
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
    if idempotency_key:
        # A short Redis lock serialises concurrent retries carrying the same key.
        with state.redis.lock(f"bf:idem:{tenant}:{idempotency_key}", timeout=30, blocking_timeout=30):
            existing = state.jobs.idempotent_job(tenant, idempotency_key)
            if existing is not None and (record := state.jobs.get(tenant, existing)) is not None:
                response.status_code = status.HTTP_200_OK
                return JobAccepted(id=record.id, state=record.state, created=False)
            with scene_lock(state.redis, tenant, [body.scene_id]):
                record = _build_job(state, tenant, body.scene_id, body.tasks, body.parameters,
                                    body.model_profile, idem=idempotency_key,
                                    callback_url=body.callback_url)  # fmt: skip
                _reserve_slots(state, tenant, [record])
                _submit(state, [record])
            state.jobs.remember_idempotent(tenant, idempotency_key, record.id)
    else:
        # Under the scene lock: a concurrent delete either sees this job (409) or came first (404).
        with scene_lock(state.redis, tenant, [body.scene_id]):
            record = _build_job(state, tenant, body.scene_id, body.tasks, body.parameters, body.model_profile,
                                callback_url=body.callback_url)  # fmt: skip
            _reserve_slots(state, tenant, [record])
            _submit(state, [record])
    return JobAccepted(id=record.id, state=record.state, created=True)


@router.get(
    "/jobs/{job_id}",
    response_model=JobRecord,
    summary="Job state, stage, progress, timings",
    responses=ERRORS,
)
def get_job(job_id: str, tenant: Tenant, state: State) -> JobRecord:
    return _load_job(state, tenant, job_id)


@router.get("/jobs", response_model=JobList, summary="List jobs, newest first", responses=ERRORS)
def list_jobs(
    tenant: Tenant,
    state: State,
    job_state: Annotated[JobState | None, Query(alias="state")] = None,
    scene_id: str | None = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    cursor: Annotated[str | None, Query(description="next_cursor of the previous page")] = None,
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
    record = _load_job(state, tenant, job_id)
    if record.state != JobState.succeeded:
        raise HTTPException(
            status.HTTP_409_CONFLICT, f"job {job_id!r} is {record.state.value}, not succeeded"
        )
    ts = state.tenant(tenant)
    prefix = f"{record.job_prefix}result/"
    try:
        summary = get_json(ts, prefix + "summary.json")
    except ArtifactNotFound:
        summary = {}
    artifacts = []
    for key in ts.list(prefix):
        rel = key[len(record.job_prefix) :]
        if state.can_presign():
            url = state.presigned_get(tenant, key, filename=PurePosixPath(key).name)
        else:
            url = f"/v1/jobs/{job_id}/artifacts/{rel}"
        artifacts.append(Artifact(path=rel, size=ts.size(key), url=url))
    return JobResult(id=job_id, state=record.state, summary=summary, artifacts=artifacts,
                     expires_in_s=state.settings.presign_expiry_s)  # fmt: skip


@router.get(
    "/jobs/{job_id}/artifacts/{path:path}",
    response_class=FileResponse,
    summary="Download one artifact (only for storage backends that cannot presign)",
    responses=ERRORS,
)
def get_artifact(job_id: str, path: str, tenant: Tenant, state: State) -> FileResponse:
    record = _load_job(state, tenant, job_id)
    try:
        key = record.job_prefix + validate_key(path)
    except InputError:
        raise not_found("artifact", path) from None
    if not path.startswith("result/") or not isinstance(state.store, LocalStore):
        raise not_found("artifact", path)
    file = state.store.root / state.tenant(tenant).prefix / key
    if not file.is_file():
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
    _load_job(state, tenant, job_id)
    record = state.jobs.request_cancel(tenant, job_id)
    assert record is not None
    return record


@router.post(
    "/batches",
    status_code=status.HTTP_202_ACCEPTED,
    response_model=BatchStatus,
    summary="Submit many jobs at once (items, or scenes x task lists)",
    tags=["batches"],
    responses={**BODY_ERRORS, 409: {"model": Problem}, 429: {"model": Problem}},
)
def submit_batch(body: BatchRequest, tenant: Tenant, state: State) -> BatchStatus:
    pairs = [(i.scene_id, i.tasks) for i in body.items]
    pairs += [(s, t) for s in body.scene_ids for t in body.task_lists]
    if not pairs:
        raise HTTPException(422, "the batch is empty: give items or scene_ids x task_lists")
    if len(pairs) > state.settings.max_batch_jobs:
        raise HTTPException(
            422,
            f"{len(pairs)} jobs; at most {state.settings.max_batch_jobs} per batch (BFIELDS_MAX_BATCH_JOBS)",
        )
    batch_id = new_id("b_")
    batch_callback = checked_callback(state.settings, body.callback_url)
    for scene_id, _ in pairs:  # before any lock: an id that cannot exist is a plain 404
        check_id("scene", scene_id, "s_")
    with scene_lock(state.redis, tenant, [s for s, _ in pairs]):
        # Validate every job before submitting any, so a bad item never leaves half a batch queued.
        records = [
            _build_job(state, tenant, s, t, body.parameters, body.model_profile, batch_id=batch_id)
            for s, t in pairs
        ]
        _reserve_slots(state, tenant, records)
        batch = BatchRecord(
            id=batch_id, tenant=tenant, job_ids=[r.id for r in records], callback_url=batch_callback
        )
        try:
            state.jobs.save_batch(batch)
        except BaseException:
            state.jobs.quota.release(tenant, [r.id for r in records])
            raise
        _submit(state, records)
    return _batch_status(state, batch)


def _batch_status(state: AppState, batch: BatchRecord) -> BatchStatus:
    jobs = [state.jobs.get(batch.tenant, j) for j in batch.job_ids]
    present = [j for j in jobs if j is not None]
    counts: dict[str, int] = {}
    for j in present:
        counts[j.state.value] = counts.get(j.state.value, 0) + 1
    progress = sum(100.0 if j.state.terminal else j.progress for j in present) / max(len(present), 1)
    return BatchStatus(
        id=batch.id, created_at=batch.created_at, progress=round(progress, 2), counts=counts,
        finished=all(j.state.terminal for j in present),
        jobs=[BatchJob(id=j.id, scene_id=j.scene_id, tasks=j.tasks, state=j.state, stage=j.stage,
                       progress=j.progress, error=j.error) for j in present],
    )  # fmt: skip


@router.get(
    "/batches/{batch_id}",
    response_model=BatchStatus,
    summary="Aggregated progress and per-job states of a batch",
    tags=["batches"],
    responses=ERRORS,
)
def get_batch(batch_id: str, tenant: Tenant, state: State) -> BatchStatus:
    check_id("batch", batch_id, "b_")
    batch = state.jobs.load_batch(tenant, batch_id)
    if batch is None:
        raise not_found("batch", batch_id)
    return _batch_status(state, batch)
