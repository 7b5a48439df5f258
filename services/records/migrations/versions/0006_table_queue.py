"""The waiting queue and the admission bound move from Redis into the jobs table (issue 28, step 6).

A committed row in state queued with no `dispatched_at` *is* a waiting job: the control process's
dispatcher takes it with ``FOR UPDATE SKIP LOCKED`` and stamps `dispatched_at`; recovery clears the
stamp to put a job whose message Redis lost back in the queue. So the `submitted` flag (a row
stored by an API that died before it pushed the job to the Redis queue) has nothing left to say
and goes with its index. Two partial indexes serve the dispatcher: the tenant's dispatched,
unfinished jobs (its dispatch bound) and its recent dispatch times (the estimated start).

Rows running without a dispatch stamp (written by an earlier release, whose dispatcher kept the
stamp in Redis) get one, so they count against their tenant's bound.

Revision ID: 0006
Revises: 0005
Created: 2026-12-06
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None

_DISPATCHED = sa.text("dispatched_at IS NOT NULL AND state IN ('queued', 'running')")
_STAMPED = sa.text("dispatched_at IS NOT NULL")


def upgrade() -> None:
    op.execute("UPDATE jobs SET dispatched_at = coalesce(started_at, updated_at) "
               "WHERE state = 'running' AND dispatched_at IS NULL")  # fmt: skip
    op.drop_index("ix_jobs_unsubmitted", table_name="jobs", postgresql_where=sa.text("NOT submitted"))
    op.drop_column("jobs", "submitted")
    op.create_index("ix_jobs_dispatched", "jobs", ["tenant", "id"], postgresql_where=_DISPATCHED)
    op.create_index("ix_jobs_dispatch_times", "jobs", ["tenant", "dispatched_at"], postgresql_where=_STAMPED)


def downgrade() -> None:
    op.drop_index("ix_jobs_dispatch_times", table_name="jobs", postgresql_where=_STAMPED)
    op.drop_index("ix_jobs_dispatched", table_name="jobs", postgresql_where=_DISPATCHED)
    op.add_column(
        "jobs", sa.Column("submitted", sa.Boolean(), server_default=sa.text("true"), nullable=False)
    )
    op.create_index(
        "ix_jobs_unsubmitted",
        "jobs",
        ["tenant", "id"],
        unique=False,
        postgresql_where=sa.text("NOT submitted"),
    )
