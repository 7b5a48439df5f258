"""A running stage's worker and heartbeat on the job's row, and the count of recovery's requeues
(issue 41): recovery decides from the row whether a worker still runs a job, not from Redis keys.

Revision ID: 0008
Revises: 0007
Created: 2026-12-07
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("jobs", sa.Column("worker", sa.String(255), nullable=True))
    op.add_column("jobs", sa.Column("heartbeat_at", sa.DateTime(timezone=True), nullable=True))
    op.add_column("jobs", sa.Column("recoveries", sa.Integer(), server_default="0", nullable=False))


def downgrade() -> None:
    op.drop_column("jobs", "recoveries")
    op.drop_column("jobs", "heartbeat_at")
    op.drop_column("jobs", "worker")
