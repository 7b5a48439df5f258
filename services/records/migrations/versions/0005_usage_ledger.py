"""The usage ledger moves from the bucket and Redis into its table (issue 28, step 5): one row per
stage execution (written by its worker) and one per job end (written in the transaction that
makes the job terminal, whoever ends it, so a job cancelled while waiting is counted too), each
with a unique `entry_id`, so a retried write never counts twice. Revision 0001's table (one row
per job, never written) is replaced. Ledger objects of earlier releases in the bucket
(``usage/<day>/``) are not imported.

Revision ID: 0005
Revises: 0004
Created: 2026-12-06
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def _ledger(columns: list[sa.Column], *constraints: sa.Constraint) -> None:
    op.create_table("usage_ledger", *columns, *constraints)
    op.create_index(
        op.f("ix_usage_ledger_tenant_recorded_at"), "usage_ledger", ["tenant", "recorded_at"], unique=False
    )


def upgrade() -> None:
    op.drop_table("usage_ledger")
    _ledger(
        [
            sa.Column("id", sa.BigInteger(), autoincrement=True, nullable=False),
            sa.Column("entry_id", sa.String(length=255), nullable=False),
            sa.Column("tenant", sa.String(length=64), nullable=False),
            sa.Column("job_id", sa.String(length=40), nullable=False),
            sa.Column("kind", sa.String(length=8), nullable=False),
            sa.Column("stage", sa.String(length=32), nullable=True),
            sa.Column("state", sa.String(length=16), nullable=True),
            sa.Column("cpu_s", sa.Double(), server_default="0", nullable=False),
            sa.Column("gpu_s", sa.Double(), server_default="0", nullable=False),
            sa.Column("bytes_stored", sa.BigInteger(), server_default="0", nullable=False),
            sa.Column(
                "recorded_at", sa.DateTime(timezone=True), server_default=sa.text("now()"), nullable=False
            ),
        ],
        sa.CheckConstraint("kind IN ('stage', 'end')", name=op.f("ck_usage_ledger_kind")),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_usage_ledger")),
        sa.UniqueConstraint("entry_id", name=op.f("uq_usage_ledger_entry_id")),
    )


def downgrade() -> None:
    op.drop_table("usage_ledger")
    _ledger(
        [
            sa.Column("id", sa.BigInteger(), autoincrement=True, nullable=False),
            sa.Column("tenant", sa.String(length=64), nullable=False),
            sa.Column("job_id", sa.String(length=40), nullable=False),
            sa.Column("state", sa.String(length=16), nullable=False),
            sa.Column("cpu_s", sa.Double(), server_default="0", nullable=False),
            sa.Column("gpu_s", sa.Double(), server_default="0", nullable=False),
            sa.Column("bytes_stored", sa.BigInteger(), server_default="0", nullable=False),
            sa.Column(
                "recorded_at", sa.DateTime(timezone=True), server_default=sa.text("now()"), nullable=False
            ),
        ],
        sa.PrimaryKeyConstraint("id", name=op.f("pk_usage_ledger")),
        sa.UniqueConstraint("job_id", name=op.f("uq_usage_ledger_job_id")),
    )
