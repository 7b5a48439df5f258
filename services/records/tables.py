"""Every table of the service's records, in one place (SQLAlchemy Core, PostgreSQL dialect).

Why Core and not the ORM: fleet operations are set statements (insert 5,000 jobs, cancel a
batch, count a queue range), written as such; rows come back as plain mappings that the jobs
domain layer turns into its pydantic records. Indexes follow what the API filters, pages and
counts by: a tenant's jobs by creation (keyset paging on (created_at, id)), by state, by batch
and by scene; the waiting queue by (tenant, priority, created_at). The first migration
and those after it (`migrations/versions/`) create exactly this schema; a test compares the two.
"""

from __future__ import annotations

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    CheckConstraint,
    Column,
    DateTime,
    Double,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    String,
    Table,
    Text,
    UniqueConstraint,
    func,
    text,
)
from sqlalchemy.dialects.postgresql import JSONB

#: Constraint names follow one convention, so migrations can name what they alter or drop.
metadata = MetaData(
    naming_convention={
        "ix": "ix_%(table_name)s_%(column_0_N_name)s",
        "uq": "uq_%(table_name)s_%(column_0_N_name)s",
        "ck": "ck_%(table_name)s_%(constraint_name)s",
        "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
        "pk": "pk_%(table_name)s",
    }
)

#: A job's states, each spelled once for the whole service: the schema's check and batch counter
#: columns here, `jobs.model.JobState` (whose `terminal` reads `TERMINAL_JOB_STATES`) above.
ACTIVE_JOB_STATES = ("queued", "running")
TERMINAL_JOB_STATES = ("succeeded", "failed", "cancelled")
JOB_STATES = ACTIVE_JOB_STATES + TERMINAL_JOB_STATES
SCENE_STATES = ("uploading", "ready", "deleting")
PRIORITIES = ("interactive", "bulk")
ID = String(40)
TENANT = String(64)
Document = JSON().with_variant(JSONB(), "postgresql")


def _when(name: str, *, nullable: bool = False) -> Column:
    return Column(
        name, DateTime(timezone=True), nullable=nullable, server_default=None if nullable else func.now()
    )


def _in(column: str, values: tuple[str, ...]) -> str:
    return f"{column} IN ({', '.join(repr(v) for v in values)})"


scenes = Table(
    "scenes",
    metadata,
    Column("id", ID, primary_key=True),
    Column("tenant", TENANT, nullable=False),
    Column("name", String(255)),
    Column("state", String(16), nullable=False),
    Column("files", Integer, nullable=False, server_default="0"),
    Column("bytes", BigInteger, nullable=False, server_default="0"),
    Column("summary", Document, nullable=False, server_default=text("'{}'")),
    Column("pending_uploads", Document, nullable=False, server_default=text("'[]'")),
    _when("created_at"),
    _when("updated_at"),
    CheckConstraint(_in("state", SCENE_STATES), name="state"),
    Index(None, "tenant", "created_at", "id"),
)

batches = Table(
    "batches",
    metadata,
    Column("id", ID, primary_key=True),
    Column("tenant", TENANT, nullable=False),
    Column("priority", String(16), nullable=False),
    Column("callback_url", Text),
    Column("job_count", Integer, nullable=False),
    Column("callback_enqueued", Boolean, nullable=False, server_default=text("false")),
    Column("idempotency_key", String(255)),
    # How many of the batch's jobs are in each state, and the summed progress of its active ones:
    # kept by triggers on `jobs` and `batch_jobs` (revision 0003) in the transaction of every change,
    # so a batch's status is this one row.
    *(Column(state, Integer, nullable=False, server_default="0") for state in JOB_STATES),
    Column("active_progress", Double, nullable=False, server_default="0"),
    _when("created_at"),
    _when("finished_at", nullable=True),
    CheckConstraint(_in("priority", PRIORITIES), name="priority"),
    Index(None, "tenant", "created_at", "id"),
)

jobs = Table(
    "jobs",
    metadata,
    Column("id", ID, primary_key=True),
    Column("tenant", TENANT, nullable=False),
    Column("scene_id", ID, nullable=False),  # no foreign key: a job's record outlives its scene
    Column("batch_id", ID, ForeignKey("batches.id", ondelete="CASCADE")),
    Column("state", String(16), nullable=False, server_default="queued"),
    Column("priority", String(16), nullable=False),
    Column("tasks", Document, nullable=False),
    Column("parameters", Document, nullable=False, server_default=text("'{}'")),
    Column("model_profile", String(64), nullable=False),
    Column("stage", String(32)),
    Column("progress", Double, nullable=False, server_default="0"),
    Column("stages_done", Document, nullable=False, server_default=text("'[]'")),
    Column("timings", Document, nullable=False, server_default=text("'{}'")),
    Column("stage_reports", Document, nullable=False, server_default=text("'{}'")),
    Column("usage", Document, nullable=False, server_default=text("'{}'")),
    Column("error", Text),
    Column("cancel_requested", Boolean, nullable=False, server_default=text("false")),
    Column("stage_runs", Integer, nullable=False, server_default="0"),
    Column("callback_url", Text),
    Column("retry_of", ID),
    Column("idempotency_key", String(255)),
    # Who runs the job's current stage and when it last said so (revision 0008): a running stage
    # beats its row every quarter of `stage_lock_ttl_s`; recovery reads staleness from here, not
    # from Redis. `recoveries` counts recovery's requeues, so a job that keeps losing its worker
    # fails with a reason instead of looping. Written only by their own statements
    # (`records.job_heartbeats`), never by a record's save.
    Column("worker", String(255)),
    _when("heartbeat_at", nullable=True),
    Column("recoveries", Integer, nullable=False, server_default="0"),
    _when("created_at"),
    _when("updated_at"),
    _when("dispatched_at", nullable=True),
    _when("started_at", nullable=True),
    _when("finished_at", nullable=True),
    # The W3C traceparent of the submission's span (revision 0011), null with tracing off: the
    # control process's dispatch and the workers' spans join the job's trace through it.
    Column("traceparent", String(64)),
    CheckConstraint(_in("state", JOB_STATES), name="state"),
    CheckConstraint(_in("priority", PRIORITIES), name="priority"),
    Index(None, "tenant", "created_at", "id"),
    Index(None, "tenant", "state", "created_at", "id"),
    Index(None, "batch_id", "id"),
    Index(None, "scene_id"),
    Index(None, "retry_of"),
    # The waiting queue: a tenant's undispatched jobs, interactive first, oldest first. Partial, so
    # it holds only waiting work however many finished jobs the table keeps.
    Index(
        "ix_jobs_waiting",
        "tenant",
        "priority",
        "created_at",
        "id",
        postgresql_where=text("state = 'queued' AND dispatched_at IS NULL"),
    ),
    # What recovery scans: the active jobs.
    Index("ix_jobs_active", "tenant", "id", postgresql_where=text("state IN ('queued', 'running')")),
    # A tenant's dispatched, unfinished jobs (its dispatch bound) and its recent dispatches (the
    # estimated start): revision 0006.
    Index(
        "ix_jobs_dispatched",
        "tenant",
        "id",
        postgresql_where=text("dispatched_at IS NOT NULL AND state IN ('queued', 'running')"),
    ),
    Index(
        "ix_jobs_dispatch_times",
        "tenant",
        "dispatched_at",
        postgresql_where=text("dispatched_at IS NOT NULL"),
    ),
)

batch_jobs = Table(
    "batch_jobs",
    metadata,
    # A batch's jobs in submission order; a retry replaces a failed job in its slot. A job can sit
    # in several batches (a re-run manifest's batch takes the earlier job of an unchanged item).
    Column("batch_id", ID, ForeignKey("batches.id", ondelete="CASCADE"), primary_key=True),
    Column("position", Integer, primary_key=True),
    Column("job_id", ID, ForeignKey("jobs.id"), nullable=False),
    Index(None, "job_id"),
)

idempotency_keys = Table(
    "idempotency_keys",
    metadata,
    Column("tenant", TENANT, primary_key=True),
    Column("endpoint", String(64), primary_key=True),
    Column("key", String(255), primary_key=True),
    Column("body_sha256", String(64), nullable=False),
    Column("target_id", ID, nullable=False),
    _when("created_at"),
)

callback_outbox = Table(
    "callback_outbox",
    metadata,
    Column("id", BigInteger, primary_key=True, autoincrement=True),
    Column("tenant", TENANT, nullable=False),
    Column("url", Text, nullable=False),
    Column("event", Document, nullable=False),
    Column("attempts", Integer, nullable=False, server_default="0"),
    _when("next_attempt_at"),  # when it is due; while an attempt runs, the end of its claim
    _when("delivered_at", nullable=True),
    Column("last_error", Text),
    _when("created_at"),
    # the receivers' idempotency key: a repeated transition queues nothing (revision 0004)
    Column("event_id", String(255), nullable=False),
    _when("dropped_at", nullable=True),  # given up after its last attempt
    UniqueConstraint("event_id"),
    Index(
        "ix_callback_outbox_due",
        "next_attempt_at",
        "id",
        postgresql_where=text("delivered_at IS NULL AND dropped_at IS NULL"),
    ),
)

usage_ledger = Table(
    "usage_ledger",
    metadata,
    # One row per stage execution (kind 'stage', written by its worker) and per job end (kind
    # 'end', written in the transaction that makes the job terminal); `entry_id` makes a retried
    # write count once (revision 0005).
    Column("id", BigInteger, primary_key=True, autoincrement=True),
    Column("entry_id", String(255), nullable=False),
    Column("tenant", TENANT, nullable=False),
    Column("job_id", ID, nullable=False),
    Column("kind", String(8), nullable=False),
    Column("stage", String(32)),
    Column("state", String(16)),
    Column("cpu_s", Double, nullable=False, server_default="0"),
    Column("gpu_s", Double, nullable=False, server_default="0"),
    Column("bytes_stored", BigInteger, nullable=False, server_default="0"),
    _when("recorded_at"),
    CheckConstraint("kind IN ('stage', 'end')", name="kind"),
    UniqueConstraint("entry_id"),
    Index(None, "tenant", "recorded_at"),
)

control_leases = Table(
    "control_leases",
    metadata,
    # A lease with a deadline and a fencing token (`records.leases`, revision 0007): the control
    # process's leader holds 'control-leader' while it renews it before `expires_at`; every take by
    # another holder bumps `token`, and a leader's statements check theirs is still current.
    Column("name", String(64), primary_key=True),
    Column("holder", String(255), nullable=False),
    Column("token", BigInteger, nullable=False),
    Column("expires_at", DateTime(timezone=True), nullable=False),
)

answers = Table(
    "answers",
    metadata,
    # A succeeded job's answers as rows (issue 42, revision 0009): per task, one row per ranked
    # object (rank 1 = best) or one row with rank 0 and found = false when the task was answered
    # "not found". Written with the success (`records.answers.replace_job`), read by the batch and
    # fleet answer routes; the job's delete removes them (the foreign key), a scene's delete by
    # `scene_id` (jobs keep no key to scenes: they outlive them). Coordinates are in the user's
    # world frame (`frame` names which one the result had: world, capture or splat).
    Column("job_id", ID, ForeignKey("jobs.id", ondelete="CASCADE"), primary_key=True),
    Column("task_index", Integer, primary_key=True),
    Column("rank", Integer, primary_key=True),
    Column("tenant", TENANT, nullable=False),
    Column("scene_id", ID, nullable=False),
    Column("finished_at", DateTime(timezone=True), nullable=False),  # the job's: "latest" per scene
    Column("task", Text, nullable=False),
    Column("found", Boolean, nullable=False),
    Column("object_id", Integer),
    Column("content_key", String(64)),
    Column("probability", Double),
    Column("best_view_score", Double),
    Column("score", Double),
    Column("ranked_by", String(16)),
    Column("num_gaussians", Integer),
    Column("frame", String(8)),
    *(Column(f"{what}_{axis}", Double) for what in ("centre", "extent", "centroid") for axis in "xyz"),
    Column("rotation", Document),
    Column("preview", String(255)),
    Column("not_found_reason", Text),
    CheckConstraint("rank >= 0 AND task_index >= 0", name="rank"),
    Index(None, "tenant", "task", "scene_id", "finished_at"),
    Index(None, "tenant", "scene_id"),
    # The fleet search's "each scene's latest job that asked the task" (revision 0010): one entry
    # per job and task (its best object or its "not found" row), scanned backwards, holding what
    # the ranking reads (an index-only scan).
    Index(
        "ix_answers_latest",
        "tenant",
        "task",
        "scene_id",
        "finished_at",
        "job_id",
        postgresql_include=["task_index", "rank", "found", "probability"],
        postgresql_where=text("rank <= 1"),
    ),
)
