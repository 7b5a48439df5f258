"""Request and response bodies of the HTTP API (pydantic), with examples for the OpenAPI page."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from bayesian_fields_service.jobs.model import JobRecord, JobState
from bayesian_fields_service.jobs.queue import Priority

# A scene is a record of the scenes domain; re-exported here, where the API's bodies live.
from bayesian_fields_service.scenes.model import SCENE_EXAMPLE_ID, SceneRecord
from bayesian_fields_service.scenes.model import SceneState as SceneState

JOB_EXAMPLE_ID = "j_0192f3a1b2c3d4e5f6a7b8"


class FieldProblem(BaseModel):
    """One refused field of a request (request validation)."""

    loc: list[str | int] = Field(
        examples=[["body", "tasks", 0]], description="Where: body, query, header, path."
    )
    msg: str = Field(examples=["String should have at least 1 character"])
    type: str = Field(examples=["string_too_short"])


class Problem(BaseModel):
    """Error body of every 4xx/5xx answer: an RFC 9457 problem (``application/problem+json``).

    ``type`` names the kind of error (a section of ``/docs/errors``, and of the docs' errors page),
    ``detail`` is always one readable string, request validation adds ``errors``."""

    type: str = Field(
        examples=["/docs/errors#validation"],
        description="The kind of error: a URI reference to its section of the errors page "
        "(resolve it against the request's URL); switch on this, not on `detail`.",
    )
    title: str = Field(examples=["The request is invalid"], description="The kind's short summary.")
    status: int = Field(examples=[422], description="The HTTP status of this answer.")
    detail: str = Field(examples=["images/frame_0003.png: image is 640x480 but its camera says 320x240"])
    instance: str = Field(examples=["/v1/scenes"], description="The path of the request refused.")
    errors: list[FieldProblem] | None = Field(
        None, description="Request validation (422) only: every refused field, with its location."
    )


class SceneList(BaseModel):
    items: list[SceneRecord]
    next_cursor: str | None = Field(None, description="Pass as `cursor` to get the next page.")


class UploadFileSpec(BaseModel):
    """One file the client will upload straight to the bucket."""

    model_config = ConfigDict(extra="forbid")
    field: Literal["splat", "cameras", "images", "transform"] = Field(
        examples=["images"], description="Same roles as the multipart form fields of POST /v1/scenes."
    )
    name: str = Field(examples=["images.zip"], min_length=1, max_length=255)
    size: int = Field(gt=0, examples=[734003200], description="Exact size in bytes.")


class UploadRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str | None = Field(None, max_length=200, examples=["kitchen-2024-05-01"])
    files: list[UploadFileSpec] = Field(min_length=1, max_length=64)


class PresignedUpload(BaseModel):
    field: str
    name: str
    upload_id: str
    part_size: int = Field(description="Every part but the last has exactly this many bytes.")
    part_urls: list[str] = Field(description="PUT part i+1 to part_urls[i]; keep each response's ETag.")


class UploadPlan(BaseModel):
    scene_id: str = Field(examples=[SCENE_EXAMPLE_ID])
    uploads: list[PresignedUpload]
    expires_in_s: int


class CompletedPart(BaseModel):
    PartNumber: int = Field(ge=1, le=10000)
    ETag: str


class CompleteRequest(BaseModel):
    """Part ETags per file name; omit to let the server list the uploaded parts itself."""

    model_config = ConfigDict(extra="forbid")
    parts: dict[str, list[CompletedPart]] | None = None
    alignment_check: bool = Field(
        True, description="false skips the geometric alignment check of the assembled scene."
    )


class JobRequest(BaseModel):
    """A job: run the pipeline on a stored scene for a task list."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "scene_id": SCENE_EXAMPLE_ID,
                    "tasks": ["get dish soap", "move hats and gloves"],
                    "parameters": {"max_frames": 40, "top_k": 3},
                    "model_profile": "default",
                }
            ]
        },
    )
    scene_id: str
    tasks: list[str] = Field(
        min_length=1,
        description="Plain-language tasks: valid UTF-8, no control characters (whitespace is "
        "collapsed) and no bidirectional controls (refused with 422), unique, bounded by "
        "BFIELDS_MAX_TASKS / BFIELDS_MAX_TASK_CHARS.",
    )
    parameters: dict[str, Any] = Field(
        default_factory=dict,
        description="`PipelineParams` fields; unknown fields are refused, numbers must be finite "
        "and within each field's documented bounds (422 naming the parameter and the limit), and "
        "the scene must support them (`depth_source: input` needs a depth map per frame).",
    )
    model_profile: str = Field("default", description="Name of a model profile configured on the workers.")
    priority: Priority = Field(
        "interactive",
        description="Class in the tenant's fair-share queue: 'interactive' jobs are dispatched ahead "
        "of the tenant's 'bulk' jobs.",
    )
    callback_url: str | None = Field(
        None,
        max_length=2000,
        description="http(s) URL that receives an HMAC-signed POST when the job ends (see the "
        "service docs: callbacks); refused when callbacks are not enabled or the host is not allowed.",
    )


class JobAccepted(BaseModel):
    id: str = Field(examples=[JOB_EXAMPLE_ID])
    state: JobState = Field(examples=["queued"])
    created: bool = Field(description="False when an Idempotency-Key matched an earlier job.")


class JobList(BaseModel):
    items: list[JobRecord]
    next_cursor: str | None = None


class Artifact(BaseModel):
    path: str = Field(examples=["result/summary.json"], description="Relative to the job folder.")
    size: int
    url: str = Field(description="Presigned GET URL (or an API URL when storage cannot presign).")


class JobResult(BaseModel):
    id: str
    state: JobState
    summary: dict[str, Any] = Field(description="Contents of result/summary.json.")
    artifacts: list[Artifact]
    expires_in_s: int


class BatchItem(BaseModel):
    model_config = ConfigDict(extra="forbid")
    scene_id: str
    tasks: list[str] = Field(min_length=1)
    idempotency_key: str | None = Field(
        None,
        min_length=1,
        max_length=200,
        pattern=r"^[\x20-\x7e]+$",
        description="Like the Idempotency-Key header of POST /v1/jobs, per item: an item whose key "
        "names an earlier job reuses that job (it is listed in this batch; no new job is made).",
    )


class BatchRequest(BaseModel):
    """Either explicit items, or every scene crossed with every task list (or both)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "scene_ids": [SCENE_EXAMPLE_ID],
                    "task_lists": [["get dish soap"], ["move hats and gloves", "water the plant"]],
                    "parameters": {"max_frames": 40},
                }
            ]
        },
    )
    items: list[BatchItem] = Field(default_factory=list)
    scene_ids: list[str] = Field(default_factory=list)
    task_lists: list[list[str]] = Field(default_factory=list)
    parameters: dict[str, Any] = Field(default_factory=dict)
    model_profile: str = "default"
    priority: Priority = Field(
        "bulk", description="Class of every job of the batch in the tenant's fair-share queue."
    )
    callback_url: str | None = Field(
        None,
        max_length=2000,
        description="http(s) URL that receives one HMAC-signed POST when every job of the batch "
        "has ended (with the counts by state); the batch's jobs send no callbacks of their own.",
    )


class BatchJob(BaseModel):
    id: str
    scene_id: str
    tasks: list[str]
    state: JobState
    stage: str | None
    progress: float
    error: str | None = None


class BatchStatus(BaseModel):
    id: str
    created_at: datetime
    progress: float = Field(description="Mean progress of the jobs, percent.")
    counts: dict[str, int] = Field(description="Jobs per state.", examples=[{"running": 2, "queued": 6}])
    finished: bool
    total: int = Field(0, description="Jobs in the batch.")
    created: int = Field(
        0,
        description="Jobs this request created (a submission: fewer than total when items reused "
        "earlier jobs by idempotency key, 0 when the batch's Idempotency-Key matched; a retry: the "
        "jobs it started again).",
    )
    jobs: list[BatchJob] = Field(
        description="Every job of the batch with ?jobs=true (a batch of at most BFIELDS_BATCH_JOBS_INLINE_MAX "
        "jobs); empty otherwise: page through the jobs with GET /v1/batches/{id}/jobs."
    )


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    checks: dict[str, str] = Field(
        default_factory=dict, examples=[{"postgresql": "ok", "redis": "ok", "storage": "ok"}]
    )
