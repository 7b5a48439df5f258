"""A job's trace context (issue 44, tracing): the W3C ``traceparent`` of the submission request's
span, so the control process's dispatch span, which starts later in another process, and the
workers' spans after it join the submission's trace. Null when tracing was off at submission.

Revision ID: 0011
Revises: 0010
Created: 2026-12-07
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0011"
down_revision = "0010"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("jobs", sa.Column("traceparent", sa.String(64), nullable=True))


def downgrade() -> None:
    op.drop_column("jobs", "traceparent")
