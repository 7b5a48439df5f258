"""Job routes: submit (idempotent), status, result links, cancel, list; plus batches of jobs
(submit, status, page, cancel, retry).

A submission is admitted (bounded by the tenant's waiting bound, 429 past it) and stored in one
transaction: its row is its place in the tenant's queue (`common.job_queue`), from which the
control process's dispatcher sends it to the workers."""

from __future__ import annotations

import hashlib
from collections.abc import Iterator, Sequence
from contextlib import AbstractContextManager, contextmanager
from datetime import UTC, datetime, timedelta
from pathlib import PurePosixPath
from typing import Annotated, Any

import redis
from fastapi import APIRouter, Header, HTTPException, Query, Response, status
from fastapi.responses import FileResponse
from pydantic import ValidationError

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import ArtifactNotFound, LocalStore, get_json, validate_key
from bayesian_fields_core.job.task_list import normalise_tasks
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_service.api.routes.callback_rules import checked_callback
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
    SceneRecord,
)
from bayesian_fields_service.api.state import (
    BODY_ERRORS,
    ERRORS,
    AppState,
    State,
    Tenant,
    check_id,
    load_scene,
    not_found,
    scene_refusals,
)
from bayesian_fields_service.common.batch_records import BatchRecord
from bayesian_fields_service.common.job_queue import AdmissionRefused, Priority, admission_limit
from bayesian_fields_service.common.jobs import JobRecord, JobState, job_digest, new_id
from bayesian_fields_service.records.locks import LockBusy, session_lock
from bayesian_fields_service.worker.metrics import JOB_KEY, read_histogram

router = APIRouter(prefix="/v1", tags=["jobs"])

#: Model profiles a job may name. The workers map "default" to BFIELDS_MODEL_PROFILE.
MODEL_PROFILES = ("default",)
def _load_job(state: AppState, tenant: str, job_id: str) -> JobRecord:
    check_id("job", job_id, "j_")
    record = state.jobs.get(tenant, job_id)
    if record is None:
        raise not_found("job", job_id)
    return record


def _with_queue_position(state: AppState, record: JobRecord) -> JobRecord:
    """Add the place in the tenant's queue and an estimated start while the job waits there."""
    if record.state != JobState.queued:
        return record
    position = state.jobs.queue.position(record.tenant, record.id, record.priority, record.created_at)
    if position is None:
        return record
    rate = state.jobs.queue.dispatch_rate(record.tenant)
    eta_s: float | None = position / rate if rate > 0 else None
    if eta_s is None and (h := _mean_job_histogram(state)):
        _, total, count = h  # no recent dispatches: mean job duration per dispatch slot
        if count:
            eta_s = total / count * position / state.settings.max_active_jobs_per_tenant
    start = datetime.now(UTC) + timedelta(seconds=eta_s) if eta_s is not None else None
    return record.model_copy(update={"queue_position": position, "estimated_start": start})


def _mean_job_histogram(state: AppState) -> tuple[list[tuple[str, float]], float, float] | None:
    """The succeeded jobs' duration histogram (Redis metrics; None while Redis is away: the
    estimate is a convenience, the answer does not wait for it)."""
    try:
        return read_histogram(state.redis, JOB_KEY.format(outcome="succeeded"))
    except redis.RedisError:
        return None


def _build_job(state: AppState, tenant: str, scene_id: str, tasks: list[str], parameters: dict[str, Any],
               model_profile: str, batch_id: str | None = None, idem: str | None = None,
               priority: Priority = "interactive",
               scenes: dict[str, SceneRecord] | None = None,
               callback_url: str | None = None, params: dict[str, Any] | None = None) -> JobRecord:  # fmt: skip
    """Validate a job request against the scene, tasks and parameters (`scenes` caches scene
    records within one request and `params` the parameters checked against each scene, so a batch
    validates once per distinct scene)."""
    if scenes is not None and scene_id in scenes:
        scene = scenes[scene_id]
    else:
        scene = load_scene(state, tenant, scene_id)
        if scenes is not None:
            scenes[scene_id] = scene
    if scene.state.value != "ready":
        raise HTTPException(
            status.HTTP_409_CONFLICT, f"scene {scene_id!r} is not ready (upload not completed)"
        )
    s = state.settings
    try:
        tasks = normalise_tasks(tasks, source="tasks", max_tasks=s.max_tasks, max_chars=s.max_task_chars)
    except InputError as exc:
        raise HTTPException(422, str(exc)) from None
    checked = params.get(scene_id) if params is not None else None
    if checked is None:
        checked = _checked_params(parameters, scene)
        if params is not None:
            params[scene_id] = checked
    if model_profile not in MODEL_PROFILES:
        raise HTTPException(
            422,
            f"model_profile {model_profile!r} is unknown; available: {', '.join(MODEL_PROFILES)}",
        )
    return JobRecord(
        id=new_id("j_"), tenant=tenant, scene_id=scene_id, tasks=tasks, parameters=dict(checked),
        model_profile=model_profile, batch_id=batch_id, idempotency_key=idem, priority=priority,
        callback_url=checked_callback(state.settings, callback_url),
    )  # fmt: skip


def _checked_params(parameters: dict[str, Any], scene: SceneRecord) -> dict[str, Any]:
    """The parameters as stored (only those set), validated and checked against the scene (422)."""
    try:
        validated = PipelineParams.model_validate(parameters)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise HTTPException(422, f"parameters.{where}: {first['msg']}") from None
    _check_params_against_scene(validated, scene.summary)
    return validated.model_dump(mode="json", exclude_unset=True)


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


def _submit(state: AppState, records: list[JobRecord], **create: Any) -> None:
    """Store jobs: one transaction that holds their scenes' rows (a scene deleted since it was
    checked: 404, `scenes.lock_ready`), admits them (429 + Retry-After when the tenant's
    unfinished jobs would exceed its waiting bound plus its dispatch bound, exact under any number
    of concurrent API processes: `job_queue.admit`) and inserts them with their batch, links and
    Idempotency-Key rows (`create` goes to `JobStore.create_many`). Committed, they wait in their
    tenant's queue; a failure leaves nothing behind, so a client's retry never runs work twice."""
    if not records:
        return
    s = state.settings
    limit = admission_limit(s.max_waiting_jobs_per_tenant, s.max_active_jobs_per_tenant)
    try:
        with scene_refusals():
            state.jobs.create_many(records, admit_limit=limit, **create)
    except AdmissionRefused as refused:
        raise HTTPException(
            status.HTTP_429_TOO_MANY_REQUESTS,
            f"{refused.active} jobs are waiting or running; at most {limit} are allowed per tenant "
            f"({s.max_waiting_jobs_per_tenant} waiting, BFIELDS_MAX_WAITING_JOBS_PER_TENANT, beyond "
            f"{s.max_active_jobs_per_tenant} dispatched, BFIELDS_MAX_ACTIVE_JOBS_PER_TENANT); this "
            f"request needs {len(records)}",
            headers={"Retry-After": str(s.retry_after_s)},
        ) from None


#: How long a request waits for another request holding the same Idempotency-Key or batch retry.
KEY_LOCK_WAIT_S = 60.0


@contextmanager
def _held(state: AppState, what: str, *names: str) -> Iterator[None]:
    """A PostgreSQL session lock on `names` (`records.locks`): requests that must not overlap
    (the same Idempotency-Key, one batch's retries) run one after another; 409 past the wait."""
    try:
        with session_lock(state.jobs.database, *names, wait_s=KEY_LOCK_WAIT_S):
            yield
    except LockBusy:
        raise HTTPException(
            status.HTTP_409_CONFLICT, f"{what} is being handled by another request; retry when it has finished"
        ) from None


def _key_lock(state: AppState, tenant: str, endpoint: str, key: str) -> AbstractContextManager[None]:
    return _held(state, f"a request with Idempotency-Key {key!r}", tenant, f"idempotency:{endpoint}", key)


def _key_reused(key: str, what: str) -> HTTPException:
    """The IETF Idempotency-Key draft's rule: a key sent again with another body is an error."""
    return HTTPException(
        422,
        f"Idempotency-Key {key!r} was first used with a different {what}; a key stands for one "
        "request: send a new key for a new request",
    )


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
        429: {"model": Problem, "description": "The tenant's waiting bound is full; see Retry-After"},
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
        digest = job_digest(body.scene_id, body.tasks, body.parameters, body.model_profile)
        # A short Redis lock serialises concurrent retries carrying the same key.
        with _key_lock(state, tenant, "jobs", idempotency_key):
            existing = state.jobs.idempotent_job(tenant, idempotency_key)
            if existing is not None and existing[1] and existing[1] != digest:
                raise _key_reused(idempotency_key, "scene, task list, parameters or model profile")
            if existing is not None and (record := state.jobs.get(tenant, existing[0])) is not None:
                response.status_code = status.HTTP_200_OK
                return JobAccepted(id=record.id, state=record.state, created=False)
            record = _build_job(state, tenant, body.scene_id, body.tasks, body.parameters,
                                body.model_profile, idem=idempotency_key, priority=body.priority,
                                callback_url=body.callback_url)  # fmt: skip
            _submit(state, [record], digests={record.id: digest}, scene_ids=[body.scene_id])
    else:
        # The insert holds the scene's row: a concurrent delete either sees this job (409) or
        # came first (404).
        record = _build_job(state, tenant, body.scene_id, body.tasks, body.parameters, body.model_profile,
                            priority=body.priority, callback_url=body.callback_url)  # fmt: skip
        _submit(state, [record], scene_ids=[body.scene_id])
    return JobAccepted(id=record.id, state=record.state, created=True)


@router.get(
    "/jobs/{job_id}",
    response_model=JobRecord,
    summary="Job state, stage, progress, timings",
    responses=ERRORS,
)
def get_job(job_id: str, tenant: Tenant, state: State) -> JobRecord:
    return _with_queue_position(state, _load_job(state, tenant, job_id))


@router.get("/jobs", response_model=JobList, summary="List jobs, newest first", responses=ERRORS)
def list_jobs(
    tenant: Tenant,
    state: State,
    job_state: Annotated[JobState | None, Query(alias="state")] = None,
    scene_id: str | None = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    cursor: Annotated[
        str | None,
        Query(pattern=r"^j_[0-9a-f]{22}$", description="next_cursor of the previous page (a job id)"),
    ] = None,
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


_BATCH_ERRORS: dict[int | str, dict[str, Any]] = {
    **BODY_ERRORS,
    200: {"model": BatchStatus, "description": "The earlier batch of this Idempotency-Key (created: 0)"},
    409: {"model": Problem, "description": "A scene is not ready"},
    429: {"model": Problem, "description": "Past the tenant's waiting bound; see Retry-After"},
}


@router.post(
    "/batches",
    status_code=status.HTTP_202_ACCEPTED,
    response_model=BatchStatus,
    summary="Submit many jobs at once (items, or scenes x task lists)",
    tags=["batches"],
    responses=_BATCH_ERRORS,
)
def submit_batch(
    body: BatchRequest,
    tenant: Tenant,
    state: State,
    response: Response,
    idempotency_key: Annotated[
        str | None,
        Header(
            max_length=200,
            description="Retries with the same key return the first batch instead of a new one.",
        ),
    ] = None,
) -> BatchStatus:
    pairs = [(i.scene_id, i.tasks, i.idempotency_key) for i in body.items]
    pairs += [(s, t, None) for s in body.scene_ids for t in body.task_lists]
    if not pairs:
        raise HTTPException(422, "the batch is empty: give items or scene_ids x task_lists")
    if len(pairs) > state.settings.max_batch_jobs:
        raise HTTPException(
            422,
            f"{len(pairs)} jobs; at most {state.settings.max_batch_jobs} per batch (BFIELDS_MAX_BATCH_JOBS)",
        )
    keys = [k for _, _, k in pairs if k]
    if len(set(keys)) != len(keys):
        raise HTTPException(422, "items: an idempotency_key appears twice in the batch")
    checked_callback(state.settings, body.callback_url)  # a refused URL is a 422 before any work
    for scene_id, _, _ in pairs:  # before any lock: an id that cannot exist is a plain 404
        check_id("scene", scene_id, "s_")
    if idempotency_key:
        digest = hashlib.sha256(body.model_dump_json().encode()).hexdigest()
        with _key_lock(state, tenant, "batches", idempotency_key):
            earlier = state.jobs.idempotent_batch(tenant, idempotency_key)
            if earlier is not None and earlier[1] and earlier[1] != digest:
                raise _key_reused(idempotency_key, "batch body")
            if earlier is not None and (batch := state.jobs.load_batch(tenant, earlier[0])) is not None:
                response.status_code = status.HTTP_200_OK
                return _batch_status(state, batch, created=0)
            return _submit_batch(state, tenant, body, pairs, idempotency_key, digest)
    return _submit_batch(state, tenant, body, pairs, None, "")


def _submit_batch(state: AppState, tenant: str, body: BatchRequest,
                  pairs: list[tuple[str, list[str], str | None]], batch_key: str | None,
                  batch_digest: str) -> BatchStatus:  # fmt: skip
    batch_id = new_id("b_")
    digests = [job_digest(None, t, body.parameters, body.model_profile) if k else "" for _, t, k in pairs]
    # Items whose idempotency key names an earlier job reuse it (a re-run batch file makes no job).
    known = state.jobs.idempotent_jobs(tenant, [k for _, _, k in pairs if k])
    for (_, _, key), digest in zip(pairs, digests, strict=True):
        if key in known and known[key][1] and known[key][1] != digest:
            raise _key_reused(key, "item (tasks, parameters or model profile)")
    found = state.jobs.get_many(tenant, [known[k][0] for _, _, k in pairs if k in known])
    earlier = [found.get(known[k][0]) if k in known else None for _, _, k in pairs]
    scenes: dict[str, SceneRecord] = {}
    params: dict[str, Any] = {}
    # Validate every job before submitting any, so a bad item never leaves half a batch queued.
    records = [
        e if e is not None else _build_job(state, tenant, s, t, body.parameters, body.model_profile,
                                           batch_id=batch_id, idem=k, priority=body.priority, scenes=scenes,
                                           params=params)
        for (s, t, k), e in zip(pairs, earlier, strict=True)
    ]  # fmt: skip
    new = [r for r in records if r.batch_id == batch_id]
    batch = BatchRecord(id=batch_id, tenant=tenant, total=len(records), priority=body.priority,
                        idempotency_key=batch_key,
                        callback_url=checked_callback(state.settings, body.callback_url))  # fmt: skip
    by_new = {r.id: d for r, d in zip(records, digests, strict=True) if r.batch_id == batch_id and d}
    _submit(state, new, digests=by_new, batch=batch, batch_job_ids=[r.id for r in records],
            batch_digest=batch_digest, scene_ids=[r.scene_id for r in new])  # fmt: skip
    return _status_of(batch, records, created=len(new))


def _status_of(batch: BatchRecord, jobs: Sequence[JobRecord | None], *, created: int = 0,
               with_jobs: bool = True) -> BatchStatus:  # fmt: skip
    """A batch's status from its jobs' records (when the answer lists them anyway)."""
    present = [j for j in jobs if j is not None]
    counts: dict[str, int] = {}
    for j in present:
        counts[j.state.value] = counts.get(j.state.value, 0) + 1
    progress = sum(100.0 if j.state.terminal else j.progress for j in present) / max(len(present), 1)
    return BatchStatus(
        id=batch.id, created_at=batch.created_at or datetime.now(UTC), progress=round(progress, 2),
        counts=counts, finished=all(j.state.terminal for j in present), total=batch.total, created=created,
        jobs=[BatchJob(id=j.id, scene_id=j.scene_id, tasks=j.tasks, state=j.state, stage=j.stage,
                       progress=j.progress, error=j.error) for j in present] if with_jobs else [],
    )  # fmt: skip


def _counted_status(state: AppState, batch: BatchRecord, *, created: int = 0) -> BatchStatus:
    """A batch's status from its row's counts (kept by the records) and its dispatched jobs' live
    progress: a few reads whatever the batch's size."""
    live = state.jobs.live_batch(batch)
    counts = {k: v for k, v in live.counts.items() if v}
    terminal = sum(v for k, v in counts.items() if JobState(k).terminal)
    progress = (100.0 * terminal + live.active_progress) / max(live.total, 1)
    return BatchStatus(
        id=batch.id, created_at=batch.created_at or datetime.now(UTC), progress=round(progress, 2),
        counts=counts, finished=live.finished, total=live.total, created=created, jobs=[],
    )  # fmt: skip


def _batch_status(
    state: AppState, batch: BatchRecord, *, created: int = 0, with_jobs: bool = True
) -> BatchStatus:
    if not with_jobs:
        return _counted_status(state, batch, created=created)
    return _status_of(batch, [j for _, j in state.jobs.batch_jobs(batch)], created=created)


def _load_batch(state: AppState, tenant: str, batch_id: str) -> BatchRecord:
    check_id("batch", batch_id, "b_")
    batch = state.jobs.load_batch(tenant, batch_id)
    if batch is None:
        raise not_found("batch", batch_id)
    return batch


@router.get(
    "/batches/{batch_id}",
    response_model=BatchStatus,
    summary="Aggregated progress and per-job states of a batch",
    tags=["batches"],
    responses=ERRORS,
)
def get_batch(
    batch_id: str,
    tenant: Tenant,
    state: State,
    jobs: Annotated[bool, Query(description="false: counts and progress only (cheaper to poll)")] = True,
) -> BatchStatus:
    return _batch_status(state, _load_batch(state, tenant, batch_id), with_jobs=jobs)


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
    limit: Annotated[int, Query(ge=1, le=500)] = 100,
    cursor: Annotated[
        str | None, Query(max_length=20, description="next_cursor of the previous page")
    ] = None,
) -> JobList:
    batch = _load_batch(state, tenant, batch_id)
    if cursor is not None and not cursor.isdigit():
        raise HTTPException(422, f"cursor {cursor!r} is not one this route returned")
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
    _load_batch(state, tenant, batch_id)
    state.jobs.cancel_batch(tenant, batch_id)  # one UPDATE of every active job
    return _counted_status(state, _load_batch(state, tenant, batch_id))


@router.post(
    "/batches/{batch_id}/retry",
    response_model=BatchStatus,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Submit the batch's failed jobs again (as new jobs that take their place in the batch)",
    tags=["batches"],
    responses={**ERRORS, 409: {"model": Problem}, 429: {"model": Problem}},
)
def retry_batch(batch_id: str, tenant: Tenant, state: State) -> BatchStatus:
    _load_batch(state, tenant, batch_id)
    with _held(state, f"the retry of batch {batch_id!r}", tenant, "batch-retry", batch_id):
        batch = _load_batch(state, tenant, batch_id)  # as it is now, under the lock
        if not batch.counts.get(JobState.failed.value):  # nothing to retry: no lock, no slot, no write
            return _counted_status(state, batch)
        failed = [j for _, j in state.jobs.batch_jobs(batch, states=[JobState.failed.value])]
        scenes: dict[str, SceneRecord] = {}
        params: dict[str, Any] = {}
        again = [
            _build_job(state, tenant, j.scene_id, j.tasks, j.parameters, j.model_profile,
                       batch_id=batch.id, idem=j.idempotency_key, priority=j.priority, scenes=scenes,
                       params=params).model_copy(update={"retry_of": j.id})
            for j in failed
        ]  # fmt: skip
        digests = {r.id: job_digest(None, r.tasks, f.parameters, r.model_profile)
                   for r, f in zip(again, failed, strict=True) if r.idempotency_key}  # fmt: skip
        _submit(state, again, digests=digests, retry_in=batch.id,  # each item's key -> its new job
                scene_ids=[r.scene_id for r in again])  # fmt: skip
    return _counted_status(state, _load_batch(state, tenant, batch_id), created=len(again))
