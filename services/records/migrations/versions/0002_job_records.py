"""Jobs and batches as the service's records (issue 28, step 2): what the bucket's manifests,
index markers, pending/active markers and idempotency objects held moves into columns.

jobs gains the overall progress, the Idempotency-Key it was submitted with and `submitted`
(false until its first message is queued), with partial indexes for recovery's two scans;
batches gain their job list in submission order, the retried map and their Idempotency-Key.

Revision ID: 0002
Revises: 0001
Created: 2026-12-04
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None

_DOCUMENT = sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), "postgresql")


def upgrade() -> None:
    op.add_column("jobs", sa.Column("progress", sa.Double(), server_default="0", nullable=False))
    op.add_column("jobs", sa.Column("idempotency_key", sa.String(length=255), nullable=True))
    op.add_column(
        "jobs", sa.Column("submitted", sa.Boolean(), server_default=sa.text("true"), nullable=False)
    )
    op.create_index(
        "ix_jobs_active", "jobs", ["tenant", "id"], unique=False,
        postgresql_where=sa.text("state IN ('queued', 'running')"),
    )  # fmt: skip
    op.create_index(
        "ix_jobs_unsubmitted",
        "jobs",
        ["tenant", "id"],
        unique=False,
        postgresql_where=sa.text("NOT submitted"),
    )
    op.add_column("batches", sa.Column("idempotency_key", sa.String(length=255), nullable=True))
    op.add_column("batches", sa.Column("job_ids", _DOCUMENT, server_default=sa.text("'[]'"), nullable=False))
    op.add_column("batches", sa.Column("retried", _DOCUMENT, server_default=sa.text("'{}'"), nullable=False))


def downgrade() -> None:
    op.drop_column("batches", "retried")
    op.drop_column("batches", "job_ids")
    op.drop_column("batches", "idempotency_key")
    op.drop_index("ix_jobs_unsubmitted", table_name="jobs", postgresql_where=sa.text("NOT submitted"))
    op.drop_index(
        "ix_jobs_active", table_name="jobs", postgresql_where=sa.text("state IN ('queued', 'running')")
    )
    op.drop_column("jobs", "submitted")
    op.drop_column("jobs", "idempotency_key")
    op.drop_column("jobs", "progress")
