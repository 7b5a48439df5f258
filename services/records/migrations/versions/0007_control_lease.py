"""The control process's leader holds a lease row with a deadline and a fencing token (issue 41).

Before, the leader held a session advisory lock, which a frozen process keeps for as long as its
connection lives; the lease must be renewed before its deadline, and every take bumps its token,
which the leader's statements check (`records.leases`).

Revision ID: 0007
Revises: 0006
Created: 2026-12-07
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "control_leases",
        sa.Column("name", sa.String(64), nullable=False),
        sa.Column("holder", sa.String(255), nullable=False),
        sa.Column("token", sa.BigInteger(), nullable=False),
        sa.Column("expires_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("name", name="pk_control_leases"),
    )


def downgrade() -> None:
    op.drop_table("control_leases")
