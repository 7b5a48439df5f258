"""Answers as rows (issue 42): a succeeded job's ranked objects and "not found" tasks, so a batch's
or a fleet's answers are one statement instead of a summary.json per job.

Revision ID: 0009
Revises: 0008
Created: 2026-12-08
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision = "0009"
down_revision = "0008"
branch_labels = None
depends_on = None


def upgrade() -> None:
    coords: list[sa.Column[float]] = [
        sa.Column(f"{what}_{axis}", sa.Double())
        for what in ("centre", "extent", "centroid")
        for axis in "xyz"
    ]
    op.create_table(
        "answers",
        sa.Column("job_id", sa.String(40), nullable=False),
        sa.Column("task_index", sa.Integer(), nullable=False),
        sa.Column("rank", sa.Integer(), nullable=False),
        sa.Column("tenant", sa.String(64), nullable=False),
        sa.Column("scene_id", sa.String(40), nullable=False),
        sa.Column("finished_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("task", sa.Text(), nullable=False),
        sa.Column("found", sa.Boolean(), nullable=False),
        sa.Column("object_id", sa.Integer()),
        sa.Column("content_key", sa.String(64)),
        sa.Column("probability", sa.Double()),
        sa.Column("best_view_score", sa.Double()),
        sa.Column("score", sa.Double()),
        sa.Column("ranked_by", sa.String(16)),
        sa.Column("num_gaussians", sa.Integer()),
        sa.Column("frame", sa.String(8)),
        *coords,
        sa.Column("rotation", postgresql.JSONB()),
        sa.Column("preview", sa.String(255)),
        sa.Column("not_found_reason", sa.Text()),
        sa.CheckConstraint("rank >= 0 AND task_index >= 0", name="ck_answers_rank"),
        sa.ForeignKeyConstraint(["job_id"], ["jobs.id"], name="fk_answers_job_id_jobs", ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("job_id", "task_index", "rank", name="pk_answers"),
    )
    op.create_index("ix_answers_tenant_task_scene_id_finished_at", "answers",
                    ["tenant", "task", "scene_id", "finished_at"])  # fmt: skip
    op.create_index("ix_answers_tenant_scene_id", "answers", ["tenant", "scene_id"])


def downgrade() -> None:
    op.drop_table("answers")
