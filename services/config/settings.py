"""Service configuration: one pydantic-settings object read from `BFIELDS_*` environment variables.

The API, the workers and the integration fixtures all build their configuration from the same
object, so a variable means the same thing in every process and in every deployment (compose,
Kubernetes, a test subprocess). Every field carries a description; `.env.example` at the repository
root lists them for operators. Secrets (`s3_secret_access_key`, API keys) are `SecretStr` or live in
a file named by `api_keys_file`, so they never show up in a repr or a log line.
"""

from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path
from typing import Literal

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from bayesian_fields_service.config.callback_secret import signing_key

GiB = 1024**3
MiB = 1024**2

#: The claim on a callback event outlasts the attempt's deadline (`callback_timeout_s`) by this.
CALLBACK_LEASE_MARGIN_S = 30.0

#: Tenant names become storage prefixes (``tenants/<tenant>/``), so they are restricted to a safe set.
TENANT_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$"

#: A dotted Python module name: what `hooks_plugins` accepts (never a file path).
MODULE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")


class ServiceSettings(BaseSettings):
    """Every knob of the batch service. Environment variable = ``BFIELDS_`` + upper-case field name;
    mappings (``api_keys``) are given as JSON."""

    # hide_input_in_errors: a refused value is never echoed in the start-up error (it may be a secret)
    model_config = SettingsConfigDict(
        env_prefix="BFIELDS_", case_sensitive=False, extra="ignore", validate_default=True,
        hide_input_in_errors=True,
    )  # fmt: skip

    # ---- records -------------------------------------------------------------------------------
    database_url: str = Field(
        "postgresql+psycopg://postgres@127.0.0.1:5432/bfields",
        description="PostgreSQL URL of the service's records (scenes, jobs, batches, idempotency keys, "
        "callback outbox, usage ledger), in SQLAlchemy form with the psycopg 3 driver.",
    )
    migrate_on_start: bool = Field(
        True,
        description="Bring the records database to the newest schema when a process starts (under "
        "the migration lock, so replicas starting together are safe); false where an init step runs "
        "`bfields-service migrate` and processes must not alter the schema.",
    )
    # ---- queue ---------------------------------------------------------------------------------
    redis_url: str = Field(
        "redis://127.0.0.1:6379/0",
        description="Redis URL used as the Celery broker, the result backend and the job-state store.",
    )
    gpu_queue: str = Field("gpu", description="Celery queue of the GPU stages (perceive, fuse).")
    cpu_queue: str = Field("cpu", description="Celery queue of the CPU stage (cluster) and housekeeping.")
    celery_visibility_timeout_s: int = Field(
        6 * 3600,
        gt=0,
        description="Seconds before Redis redelivers an unacknowledged task to another worker. Must exceed "
        "the longest stage (tasks are acked late so a crashed worker's task is redelivered).",
    )
    celery_prefetch_multiplier: int = Field(
        1, ge=1, description="Tasks a worker process reserves ahead; 1 keeps long GPU stages fair."
    )
    worker_device: Literal["auto", "cuda", "cpu"] = Field(
        "auto", description="Torch device of the GPU-queue worker; 'auto' picks CUDA when available."
    )

    # ---- object storage ------------------------------------------------------------------------
    storage_backend: Literal["s3", "local"] = Field(
        "local", description="'s3' for any S3-compatible store (AWS, MinIO, ...); 'local' for a folder."
    )
    local_storage_root: Path = Field(
        Path("./data/store"), description="Folder of the 'local' backend (shared by API and workers)."
    )
    s3_endpoint_url: str | None = Field(
        None, description="S3 endpoint, e.g. http://minio:9000; unset for AWS S3 in s3_region."
    )
    s3_public_endpoint_url: str | None = Field(
        None,
        description="Endpoint the presigned links name, where clients reach the store at another "
        "address than the service does (compose: the published http://127.0.0.1:9000 for the "
        "containers' http://minio:9000); unset = s3_endpoint_url.",
    )
    s3_region: str = Field("us-east-1", description="S3 region name (used for request signing).")
    s3_bucket: str = Field(
        "bayesian-fields", min_length=3, max_length=63, description="Bucket holding all artifacts."
    )
    s3_access_key_id: str | None = Field(
        None, description="S3 access key id; unset to use the default AWS credential chain (IAM role)."
    )
    s3_secret_access_key: SecretStr | None = Field(None, description="S3 secret access key.")
    s3_addressing_style: Literal["auto", "path", "virtual"] = Field(
        "path", description="Bucket addressing; 'path' suits MinIO and most self-hosted servers."
    )
    s3_multipart_threshold_bytes: int = Field(
        64 * MiB, ge=5 * MiB, description="Objects at least this large are uploaded in parts."
    )
    s3_multipart_chunk_bytes: int = Field(
        16 * MiB, ge=5 * MiB, description="Part size of multipart uploads (S3's minimum is 5 MiB)."
    )
    s3_max_attempts: int = Field(
        5, ge=1, le=20, description="Attempts per S3 request on transient errors (exponential backoff)."
    )
    presign_expiry_s: int = Field(
        3600, ge=60, le=7 * 24 * 3600, description="Lifetime of presigned upload/download URLs."
    )

    # ---- authentication ------------------------------------------------------------------------
    api_keys: dict[str, str] = Field(
        default_factory=dict,
        description="JSON object API key -> tenant. A key may be stored as 'sha256:<hex>' of the key.",
    )
    api_keys_file: Path | None = Field(
        None,
        description="Secret file with more keys: a JSON object like api_keys, or lines '<key> <tenant>' "
        "('#' starts a comment). Re-read on each lookup, so keys rotate without a restart.",
    )

    # ---- metrics (GET /metrics) -------------------------------------------------------------------
    metrics_token: SecretStr | None = Field(
        None,
        description="Bearer token GET /metrics requires (`Authorization: Bearer <token>`; not an API "
        "key). Unset, /metrics answers 404 unless metrics_anonymous is true.",
    )
    metrics_anonymous: bool = Field(
        False,
        description="Serve GET /metrics without a token: only where no client of the API can reach it "
        "(a port or network of the operator's own).",
    )
    metrics_per_tenant: bool = Field(
        False,
        description="Label the waiting-jobs gauge and the queue-wait histogram per tenant (the tenants' "
        "names and loads, to whoever holds the metrics token); false: one series over all tenants.",
    )

    # ---- input limits (checked at the edge, before any work is queued) ---------------------------
    max_upload_bytes: int = Field(4 * GiB, gt=0, description="Largest single upload (scene archive).")
    max_archive_members: int = Field(50_000, gt=0, description="Most files a scene archive may contain.")
    max_archive_uncompressed_bytes: int = Field(
        16 * GiB, gt=0, description="Largest total uncompressed size of a scene archive (zip-bomb guard)."
    )
    max_gaussians: int = Field(20_000_000, gt=0, description="Most Gaussians a splat may contain.")
    max_frames: int = Field(10_000, gt=0, description="Most posed images a scene may contain.")
    max_tasks: int = Field(256, gt=0, description="Most task prompts in one job.")
    max_task_chars: int = Field(200, gt=0, description="Longest task prompt, in characters.")
    max_batch_jobs: int = Field(
        50_000, gt=0, description="Most jobs in one batch submission (accepted whole, or refused whole)."
    )
    api_bulk_lane: bool = Field(
        True,
        description="Each API process serves POST /v1/batches through a child process of its own "
        "(api/bulk_lane.py), so parsing and storing a fleet-sized batch never holds the interpreter "
        "that answers other tenants' requests; false handles batches in the API process itself.",
    )
    api_bulk_lane_wait_s: float = Field(
        10.0,
        gt=0,
        le=600,
        description="How long a batch submission waits for the bulk lane to take it (a free slot) or "
        "to show it is alive (it answers a ping) before it is answered 503 + Retry-After: a frozen or "
        "overloaded lane is answered in about this long, while a lane that is alive may take as long "
        "as a fleet-sized batch needs.",
    )
    batch_jobs_inline_max: int = Field(
        1000,
        ge=0,
        description="Most jobs GET /v1/batches/{id}?jobs=true lists in its answer; a larger batch is "
        "refused with 422 (read its jobs a page at a time from GET /v1/batches/{id}/jobs). Without "
        "jobs=true the answer is the batch's counts and progress only, whatever its size.",
    )
    api_tenant_concurrency: int = Field(
        4,
        ge=1,
        le=1000,
        description="Requests of one tenant an API process serves at once (api/tenant_gate.py); the "
        "tenant's further requests wait in its own first-in-first-out queue, so other tenants' "
        "requests never wait behind them. Sized for one uvicorn process: its sync routes share one "
        "interpreter and a 20-connection records pool, and a request of another tenant waits for "
        "at most this many of a busy tenant's (see docs/service/api.md, 'Fairness between tenants').",
    )
    api_tenant_queue: int = Field(
        64,
        ge=0,
        le=100_000,
        description="Requests of one tenant that may wait for its api_tenant_concurrency slots on an "
        "API process; past that the request is answered 429 + Retry-After at once.",
    )
    api_tenant_streams: int = Field(
        8,
        ge=0,
        le=10_000,
        description="Streamed answers of one tenant (SSE events, CSV / JSON Lines exports, result "
        "zips) an API process keeps open without holding a request slot; a stream past this keeps "
        "one of the tenant's api_tenant_concurrency slots until it ends.",
    )
    api_tenant_rate: float = Field(
        50.0,
        ge=0,
        le=1_000_000,
        description="Requests per second one tenant may sustain on an API process (api/tenant_rate.py, "
        "a token bucket of api_tenant_burst), so a tenant polling from many threads cannot take the "
        "CPU the other tenants' requests need. A request past it waits for its turn (1 / rate apart) "
        "up to api_tenant_rate_delay_s; past that it is answered 429 with Retry-After and RateLimit "
        "headers before any route runs. 0: no rate bound.",
    )
    api_tenant_rate_delay_s: float = Field(
        1.0,
        ge=0,
        le=60,
        description="The longest a tenant's request past its api_tenant_rate waits for its turn "
        "before it is answered 429 instead.",
    )
    api_tenant_burst: int = Field(
        20,
        ge=1,
        le=1_000_000,
        description="Requests one tenant may send at once on an API process above its api_tenant_rate "
        "(the token bucket's size): a client's natural bursts, such as fetching a result's files.",
    )
    api_body_timeout_s: float = Field(
        30.0,
        gt=0,
        le=3600,
        description="Request bodies: the longest wait for the next chunk of a body, and the time a "
        "body may take in all, plus one second for each api_body_min_rate_bytes of it. A client "
        "slower than that gets 408 and a closed connection, so dripped bodies cannot hold "
        "connections.",
    )
    api_body_min_rate_bytes: int = Field(
        64 * 1024,
        gt=0,
        description="Bytes per second a large body is allowed on top of api_body_timeout_s (a 4 GiB "
        "upload at this rate: 30 s + 65,536 s).",
    )

    # ---- jobs ------------------------------------------------------------------------------------
    model_profile: Path | None = Field(
        None, description="Model profile YAML (segmenter, encoder, calibration); unset = built-in default."
    )
    job_soft_time_limit_s: int = Field(
        4 * 3600, gt=0, description="Per-stage soft time limit: the stage is cancelled cleanly."
    )
    job_time_limit_s: int = Field(
        4 * 3600 + 300, gt=0, description="Per-stage hard time limit: the worker process is killed."
    )
    job_max_retries: int = Field(
        3, ge=0, description="Redeliveries of a stage after a worker crash or a transient error."
    )
    max_active_jobs_per_tenant: int = Field(
        16,
        gt=0,
        description="Jobs of one tenant dispatched to the workers at a time (in a Celery queue or "
        "running); the rest wait in the tenant's fair-share queue. Admission is bounded apart, by "
        "max_waiting_jobs_per_tenant.",
    )
    max_waiting_jobs_per_tenant: int = Field(
        100_000,
        gt=0,
        description="Jobs a tenant may have waiting beyond those dispatched: a submission is refused "
        "with 429 + Retry-After only when the tenant's unfinished jobs would exceed this plus "
        "max_active_jobs_per_tenant.",
    )
    tenant_weights: dict[str, float] = Field(
        default_factory=dict,
        description="JSON object tenant -> weight of its share of the workers while several tenants "
        "have jobs waiting (a tenant of weight 2 gets twice the dispatches of one of weight 1). "
        "Tenants not named weigh 1.",
    )
    dispatch_queue_depth: int = Field(
        2,
        ge=1,
        le=1000,
        description="Messages the dispatcher keeps waiting in the GPU queue ahead of the workers. "
        "Small keeps the order fair (a new tenant's job waits behind at most this many); at least "
        "the number of GPU worker processes that may fall idle at once keeps them busy.",
    )
    dispatch_interval_s: float = Field(
        0.5, gt=0, le=60, description="Seconds between two rounds of the dispatcher."
    )
    control_election_interval_s: float = Field(
        1.0,
        gt=0,
        le=60,
        description="Seconds between a standby control process's tries to become the leader (and the "
        "leader's renewals of its lease): a leader that resigns is replaced within about this, one that is "
        "killed, frozen or cut off within `control_lease_ttl_s` plus this.",
    )
    control_lease_ttl_s: float = Field(
        6.0,
        gt=0,
        le=300,
        description="Seconds the control leader's lease lasts after its last renewal (it renews every "
        "election interval). A leader that is frozen or cut off from the database is replaced within "
        "about this plus one election interval; keep it several election intervals long.",
    )
    control_host: str = Field(
        "127.0.0.1",
        description="Address the control process's /healthz and /readyz listen on: loopback by "
        "default; the images set 0.0.0.0, so a Kubernetes probe reaches the pod's address.",
    )
    control_port: int = Field(
        8001,
        ge=0,
        le=65535,
        description="Port of the control process's /healthz and /readyz (0: any free port, logged).",
    )
    stage_lock_ttl_s: int = Field(
        60,
        ge=4,
        le=24 * 3600,
        description="A stage lock expires this long after its holder stops renewing it (a crashed "
        "worker's stage is taken over then); the holder renews it every quarter of that.",
    )
    recovery_interval_s: float = Field(
        15.0, gt=0, le=3600, description="Seconds between the control process's scans for orphaned jobs."
    )
    record_write_budget_s: float = Field(
        600.0,
        gt=0,
        le=24 * 3600,
        description="How long a worker keeps retrying the write of a stage's or a job's end while the "
        "records database is unreachable (backoff up to 8 s between tries); past it, recovery finishes "
        "the job from its row once the database answers.",
    )
    message_wait_s: float = Field(
        1800.0,
        gt=0,
        le=7 * 24 * 3600,
        description="How long recovery trusts that a dispatched job no worker has claimed yet still has "
        "its message waiting in a worker queue (its live progress says 'waiting'); past it the job is "
        "put back in the queue. Longer than the longest wait of a stage message behind others.",
    )
    max_recoveries: int = Field(
        5,
        ge=1,
        le=1000,
        description="How many times recovery puts a job that lost its worker back in the queue; the "
        "next time it fails with the reason instead of looping.",
    )
    recovery_grace_s: float = Field(
        20.0,
        ge=0,
        description="How long a job must look orphaned (no worker's heartbeat on its row within "
        "BFIELDS_STAGE_LOCK_TTL_S, no queued task) before a scan puts it back in the queue.",
    )

    # ---- outages (request path of the API) -------------------------------------------------------
    api_backend_timeout_s: float = Field(
        1.0,
        gt=0,
        le=30,
        description="Connect timeout of the API's calls to Redis, the broker and the bucket. With "
        "api_backend_attempts it bounds how long a request waits during an outage before it is "
        "answered 503 (workers keep their own, patient retries).",
    )
    api_backend_attempts: int = Field(
        2, ge=1, le=10, description="Attempts of each API call to Redis / the bucket before 503."
    )
    retry_after_s: int = Field(
        5, ge=1, le=3600, description="Retry-After seconds of a 503 (backend outage) or 429 (quota) answer."
    )

    # ---- disk and housekeeping -------------------------------------------------------------------
    worker_scene_cache_dir: Path | None = Field(
        None,
        description="Folder of the workers' scene copies (one per scene and content version, shared "
        "by the pool processes of a host); unset = <temp dir>/bfields-scene-cache.",
    )
    worker_scene_cache_max_bytes: int = Field(
        20 * GiB,
        gt=0,
        description="Bound of that folder: least recently used copies not in use are deleted beyond it "
        "(a scene larger than the bound is still served). Size the worker's disk at least this.",
    )
    orphan_max_age_s: int = Field(
        6 * 3600,
        ge=1,
        description="Age after which the API's sweeper removes what a killed API left: upload temp "
        "folders of dead processes, multipart uploads and staged scene files no scene record names.",
    )
    orphan_sweep_interval_s: int = Field(
        3600,
        ge=1,
        description="Seconds between two orphan sweeps (the control process sweeps the bucket, each API "
        "process its own upload temp folders; one also runs at start).",
    )

    # ---- single flight (one perception / visibility computation per scene) -----------------------
    flight_lock_ttl_s: int = Field(
        30,
        ge=2,
        le=3600,
        description="A cache-filling lock (`bf:flight:*`) expires this long after its holder stops "
        "renewing it (a crashed worker's); the holder renews it every third of that.",
    )
    flight_wait_timeout_s: float = Field(
        4 * 3600,
        gt=0,
        description="Longest a job waits for another job filling the same scene's perception or "
        "visibility cache; past it, it computes the frames itself (never a deadlock).",
    )
    flight_poll_s: float = Field(
        0.25, gt=0, le=10, description="How often a waiting job looks whether the lock was released."
    )

    # ---- notifications (job / batch callbacks, server-sent events) --------------------------------
    callback_secret: SecretStr | None = Field(
        None,
        description="Secret of the HMAC-SHA256 signatures of every callback POST: 'whsec_' + base64 "
        "of the key (the Standard Webhooks form; `bfields-service callback-secret --new` makes one), or "
        "any other text, whose UTF-8 bytes are the key (`bfields-service callback-secret` prints its "
        "'whsec_' form for receivers). Unset: jobs and batches with a callback_url are refused (422).",
    )
    callback_allowed_hosts: list[str] = Field(
        default_factory=list,
        description="JSON list of host names (or '*.example.com' suffixes) callback URLs may name; "
        "empty = any public host.",
    )
    callback_allow_private: bool = Field(
        False,
        description="Allow callback URLs that name or resolve to addresses that are not globally "
        "routable (loopback, private, link-local, shared, reserved, ...; unspecified and multicast "
        "stay refused). Off: a tenant cannot make the service call its own network.",
    )
    callback_timeout_s: float = Field(
        10.0,
        gt=0,
        le=120,
        description="Deadline of one callback attempt as a whole: resolving the host, connecting, "
        "sending and reading the answer (a receiver that drips bytes is cut off at it). The claim "
        "on the event lasts this plus CALLBACK_LEASE_MARGIN_S (`callback_lease_s`).",
    )
    callback_max_response_bytes: int = Field(
        64 * 1024,
        ge=0,
        le=16 * MiB,
        description="At most this much of a receiver's answer is read; then the connection is closed "
        "(only the status matters).",
    )
    callback_threads: int = Field(
        4,
        ge=1,
        le=64,
        description="Callback attempts in flight at once per worker process (its delivery threads).",
    )
    callback_per_destination: int = Field(
        2,
        ge=1,
        le=64,
        description="Callback attempts in flight at once per worker process to one host:port, so a "
        "slow receiver holds at most this many delivery threads and delays only its own events (keep it "
        "below BFIELDS_CALLBACK_THREADS).",
    )
    callback_max_attempts: int = Field(
        12, ge=1, le=100, description="Attempts per callback before it is dropped (logged)."
    )
    callback_backoff_s: float = Field(
        2.0, gt=0, description="Delay before the second attempt; doubles per attempt (with jitter)."
    )
    callback_backoff_max_s: float = Field(
        900.0, gt=0, description="Longest delay between two attempts of one callback."
    )
    callback_poll_s: float = Field(
        1.0, gt=0, le=60, description="How often a worker's delivery thread looks for callbacks due."
    )
    events_poll_s: float = Field(
        1.0, gt=0, le=60, description="How often a batch's event stream (SSE) reads its jobs' states."
    )
    events_max_s: float = Field(
        3600.0, gt=0, description="Longest one event stream stays open (clients reconnect)."
    )

    # ---- accounting ------------------------------------------------------------------------------
    usage_max_days: int = Field(
        366, ge=1, le=3660, description="Longest period GET /v1/usage answers in one request (days)."
    )

    # ---- misc ------------------------------------------------------------------------------------
    hooks_plugins: list[str] = Field(
        default_factory=list,
        description="JSON list of Python modules (installed code, named by module) whose "
        "install(registry, settings) registers functions on the service's hook points "
        "(bayesian_fields_service.hooks: tracing, fault injection, the tests' pause points). "
        "Empty: every hook point is a no-op.",
    )
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = Field(
        "INFO",
        description="Level of the services' own loggers (bayesian_fields_service.*, bayesian_fields_core.*).",
    )
    log_format: Literal["text", "json"] = Field(
        "text",
        description="How the API, control and worker processes write their log lines: 'text' for a "
        "terminal, or 'json' (one JSON object a line with time, level, logger, message and, where "
        "known, job_id, tenant, stage, trace_id and span_id) for a log pipeline.",
    )
    tracing: str = Field(
        "",
        description="OpenTelemetry tracing: '' (off unless OTEL_EXPORTER_OTLP_ENDPOINT is set, then "
        "'otlp'), 'off', 'otlp' (OTLP over HTTP, configured by the standard OTEL_* variables), "
        "'console' (spans as JSON lines on stderr) or 'file:PATH' (spans appended to PATH as JSON "
        "lines). Needs the 'tracing' extra (opentelemetry-sdk and the instrumentations).",
    )

    @field_validator("hooks_plugins")
    @classmethod
    def _check_hooks_plugins(cls, v: list[str]) -> list[str]:
        bad = [name for name in v if not MODULE_NAME.fullmatch(name)]
        if bad:
            raise ValueError(f"hooks_plugins takes Python module names (like 'package.module'), not {bad}")
        return v

    @field_validator("callback_secret")
    @classmethod
    def _check_callback_secret(cls, v: SecretStr | None) -> SecretStr | None:
        if v is not None:
            signing_key(v.get_secret_value())  # a malformed 'whsec_' value is refused at start
        return v

    @field_validator("tracing")
    @classmethod
    def _check_tracing(cls, v: str) -> str:
        if v in ("", "off", "otlp", "console") or (v.startswith("file:") and len(v) > len("file:")):
            return v
        raise ValueError(f"BFIELDS_TRACING takes '', off, otlp, console or file:PATH, not {v!r}")

    @field_validator("redis_url")
    @classmethod
    def _check_redis_url(cls, v: str) -> str:
        if not v.startswith(("redis://", "rediss://", "unix://")):
            raise ValueError("BFIELDS_REDIS_URL must start with redis://, rediss:// or unix://")
        return v

    @field_validator("api_keys")
    @classmethod
    def _check_tenants(cls, v: dict[str, str]) -> dict[str, str]:
        for key, tenant in v.items():
            if not key:
                raise ValueError("BFIELDS_API_KEYS: empty key")
            if not re.match(TENANT_PATTERN, tenant):
                raise ValueError(
                    f"BFIELDS_API_KEYS: invalid tenant name {tenant!r} (allowed {TENANT_PATTERN})"
                )
        return v

    @field_validator("tenant_weights")
    @classmethod
    def _check_weights(cls, v: dict[str, float]) -> dict[str, float]:
        for tenant, weight in v.items():
            if not weight > 0 or weight == float("inf"):
                raise ValueError(f"BFIELDS_TENANT_WEIGHTS: weight of {tenant!r} must be a positive number")
        return v

    @property
    def callback_lease_s(self) -> float:
        """How long a claimed callback event stays claimed: the attempt's deadline plus a margin
        for the bookkeeping around it, so an attempt never outlives its claim (derived, not set,
        so the two cannot be configured out of order)."""
        return self.callback_timeout_s + CALLBACK_LEASE_MARGIN_S

    @property
    def tracing_mode(self) -> str:
        """What `tracing` resolves to: its value, or when empty 'otlp' if the standard
        OTEL_EXPORTER_OTLP_ENDPOINT (or ..._TRACES_ENDPOINT) is set, else 'off'. Read here, the one
        module that reads the environment, so "off unless the endpoint is set" holds everywhere."""
        if self.tracing:
            return self.tracing
        import os

        endpoints = ("OTEL_EXPORTER_OTLP_ENDPOINT", "OTEL_EXPORTER_OTLP_TRACES_ENDPOINT")
        return "otlp" if any(os.environ.get(name) for name in endpoints) else "off"

    def weight(self, tenant: str) -> float:
        """The tenant's fair-share weight (1 unless BFIELDS_TENANT_WEIGHTS names it)."""
        return self.tenant_weights.get(tenant, 1.0)

    @model_validator(mode="after")
    def _check_consistency(self) -> ServiceSettings:
        if self.job_time_limit_s < self.job_soft_time_limit_s:
            raise ValueError("BFIELDS_JOB_TIME_LIMIT_S must be >= BFIELDS_JOB_SOFT_TIME_LIMIT_S")
        if self.celery_visibility_timeout_s < self.job_time_limit_s:
            raise ValueError(
                "BFIELDS_CELERY_VISIBILITY_TIMEOUT_S must be >= BFIELDS_JOB_TIME_LIMIT_S, otherwise Redis "
                "redelivers a task that is still running"
            )
        if self.control_lease_ttl_s < 2 * self.control_election_interval_s:
            raise ValueError(
                "BFIELDS_CONTROL_LEASE_TTL_S must be at least twice BFIELDS_CONTROL_ELECTION_INTERVAL_S, "
                "otherwise the leader's lease runs out between two of its renewals"
            )
        if (self.s3_access_key_id is None) != (self.s3_secret_access_key is None):
            raise ValueError("set both BFIELDS_S3_ACCESS_KEY_ID and BFIELDS_S3_SECRET_ACCESS_KEY, or neither")
        return self


@lru_cache(maxsize=1)
def get_settings() -> ServiceSettings:
    """The process-wide settings, read once from the environment (`get_settings.cache_clear()` to
    re-read, e.g. in tests)."""
    return ServiceSettings()


def apply_log_level(settings: ServiceSettings) -> None:
    """Set BFIELDS_LOG_LEVEL on the project's loggers (handlers stay with uvicorn / Celery)."""
    import logging

    for name in ("bayesian_fields_service", "bayesian_fields_core"):
        logging.getLogger(name).setLevel(settings.log_level)
