"""The fleet search's index (issue 42, item 7): each job's row of rank <= 1 per task (its best
object or its "not found" row) by tenant, task, scene and finish, so "each scene's latest job
that asked the task" reads one index entry per job (with the columns the ranking needs, so an
index-only scan) instead of sorting every ranked row of the task (bench/bench_answers.py: 50,000
jobs x 8 tasks x 5 objects: 1.1 s a search before).

Revision ID: 0010
Revises: 0009
Created: 2026-12-08
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0010"
down_revision = "0009"
branch_labels = None
depends_on = None

_LATEST = sa.text("rank <= 1")


def upgrade() -> None:
    op.create_index("ix_answers_latest", "answers", ["tenant", "task", "scene_id", "finished_at", "job_id"],
                    postgresql_include=["task_index", "rank", "found", "probability"],
                    postgresql_where=_LATEST)  # fmt: skip


def downgrade() -> None:
    op.drop_index("ix_answers_latest", table_name="answers", postgresql_where=_LATEST)
