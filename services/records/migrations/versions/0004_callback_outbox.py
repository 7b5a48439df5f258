"""The callback outbox moves from Redis into its table (issue 28, step 4): an event row is written
in the transaction of the state change that causes it (a transactional outbox), so losing Redis
loses no callback, and a crash before the commit loses the change and its event together.

`event_id` (the receivers' idempotency key) is unique, so a repeated transition queues nothing;
`next_attempt_at` is both when an event is due and, while an attempt runs, the end of its claim;
`dropped_at` marks an event given up after its last attempt (kept with its `last_error`), and the
partial index holds only open events, however many delivered ones the table keeps.

Revision ID: 0004
Revises: 0003
Created: 2026-12-06
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("callback_outbox", sa.Column("event_id", sa.String(length=255), nullable=False))
    op.add_column("callback_outbox", sa.Column("dropped_at", sa.DateTime(timezone=True), nullable=True))
    op.create_unique_constraint(op.f("uq_callback_outbox_event_id"), "callback_outbox", ["event_id"])
    op.drop_index(
        "ix_callback_outbox_due",
        table_name="callback_outbox",
        postgresql_where=sa.text("delivered_at IS NULL"),
    )
    op.create_index(
        "ix_callback_outbox_due", "callback_outbox", ["next_attempt_at", "id"], unique=False,
        postgresql_where=sa.text("delivered_at IS NULL AND dropped_at IS NULL"),
    )  # fmt: skip
    op.drop_column("callback_outbox", "claimed_until")


def downgrade() -> None:
    op.add_column("callback_outbox", sa.Column("claimed_until", sa.DateTime(timezone=True), nullable=True))
    op.drop_index(
        "ix_callback_outbox_due", table_name="callback_outbox",
        postgresql_where=sa.text("delivered_at IS NULL AND dropped_at IS NULL"),
    )  # fmt: skip
    op.create_index(
        "ix_callback_outbox_due", "callback_outbox", ["next_attempt_at"], unique=False,
        postgresql_where=sa.text("delivered_at IS NULL"),
    )  # fmt: skip
    op.drop_constraint(op.f("uq_callback_outbox_event_id"), "callback_outbox", type_="unique")
    op.drop_column("callback_outbox", "dropped_at")
    op.drop_column("callback_outbox", "event_id")
