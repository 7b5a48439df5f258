"""Fleet operations as statements (issue 28, step 3): a batch's jobs are rows of `batch_jobs`
(batch, position, job), and its per-state counts are columns of its `batches` row kept by
triggers, so a batch's status is one row read and a page one index range, whatever its size.

Why a link table and not `jobs.batch_id`: a re-run manifest's batch takes the earlier job of
each unchanged item (its Idempotency-Key), so one job can belong to several batches; a retry
replaces a failed job in its slot (`UPDATE batch_jobs SET job_id`), the new job's `retry_of`
naming the old one. Why triggers: every path that changes a job's state (a worker's save, one
cancel, a batch's one-statement cancel, recovery) keeps every batch's counts exact in the same
transaction, with no application code to forget; they are statement-level with transition
tables, so a 5,000-row UPDATE runs each trigger once.

Data: the `batches.job_ids` lists and `retried` maps of revision 0002 become `batch_jobs` rows
and `jobs.retry_of`, then the columns go; the counts are computed once from the rows.

Revision ID: 0003
Revises: 0002
Created: 2026-12-06
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None

_DOCUMENT = sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), "postgresql")
COUNT_COLUMNS = ("queued", "running", "succeeded", "failed", "cancelled")

# One function adds the signed contribution of (batch, state, progress) rows to the batches' count
# columns; the triggers only say which rows enter (+1) and leave (-1).
_APPLY = """
CREATE FUNCTION bf_apply_batch_deltas(changes jsonb) RETURNS void LANGUAGE sql AS $$
  WITH c AS (
    SELECT (e->>'batch_id') AS batch_id, (e->>'state') AS state,
           (e->>'progress')::double precision AS progress, (e->>'sign')::int AS sign
    FROM jsonb_array_elements(changes) AS e
  ), d AS (
    SELECT batch_id,
      coalesce(sum(sign) FILTER (WHERE state = 'queued'), 0) AS queued,
      coalesce(sum(sign) FILTER (WHERE state = 'running'), 0) AS running,
      coalesce(sum(sign) FILTER (WHERE state = 'succeeded'), 0) AS succeeded,
      coalesce(sum(sign) FILTER (WHERE state = 'failed'), 0) AS failed,
      coalesce(sum(sign) FILTER (WHERE state = 'cancelled'), 0) AS cancelled,
      coalesce(sum(sign * progress) FILTER (WHERE state IN ('queued', 'running')), 0) AS progress
    FROM c GROUP BY batch_id
  )
  UPDATE batches b SET
    queued = b.queued + d.queued, running = b.running + d.running,
    succeeded = b.succeeded + d.succeeded, failed = b.failed + d.failed,
    cancelled = b.cancelled + d.cancelled, active_progress = b.active_progress + d.progress
  FROM d WHERE b.id = d.batch_id
$$;
"""

# jobs: a statement that changed states or progress moves each changed job's contribution in
# every batch that holds it.
_JOBS_TRIGGER = """
CREATE FUNCTION bf_batch_counts_on_jobs() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
  PERFORM bf_apply_batch_deltas(coalesce((
    SELECT jsonb_agg(x) FROM (
      SELECT bj.batch_id, n.state, n.progress, 1 AS sign
        FROM new_rows n JOIN old_rows o ON o.id = n.id JOIN batch_jobs bj ON bj.job_id = n.id
        WHERE n.state IS DISTINCT FROM o.state OR n.progress IS DISTINCT FROM o.progress
      UNION ALL
      SELECT bj.batch_id, o.state, o.progress, -1
        FROM new_rows n JOIN old_rows o ON o.id = n.id JOIN batch_jobs bj ON bj.job_id = o.id
        WHERE n.state IS DISTINCT FROM o.state OR n.progress IS DISTINCT FROM o.progress
    ) x), '[]'::jsonb));
  RETURN NULL;
END $$;
CREATE TRIGGER bf_batch_counts_on_jobs AFTER UPDATE ON jobs
  REFERENCING OLD TABLE AS old_rows NEW TABLE AS new_rows
  FOR EACH STATEMENT EXECUTE FUNCTION bf_batch_counts_on_jobs();
"""

# batch_jobs: a job entering a batch adds its current state, one leaving removes it (a retry's
# UPDATE of job_id does both).
_LINK_TRIGGERS = """
CREATE FUNCTION bf_batch_counts_on_links() RETURNS trigger LANGUAGE plpgsql AS $$
DECLARE entering jsonb := '[]'; leaving jsonb := '[]';
BEGIN
  IF TG_OP IN ('INSERT', 'UPDATE') THEN
    SELECT coalesce(jsonb_agg(x), '[]') INTO entering FROM (
      SELECT l.batch_id, j.state, j.progress, 1 AS sign FROM new_links l JOIN jobs j ON j.id = l.job_id
    ) x;
  END IF;
  IF TG_OP IN ('DELETE', 'UPDATE') THEN
    SELECT coalesce(jsonb_agg(x), '[]') INTO leaving FROM (
      SELECT l.batch_id, j.state, j.progress, -1 AS sign FROM old_links l JOIN jobs j ON j.id = l.job_id
    ) x;
  END IF;
  PERFORM bf_apply_batch_deltas(entering || leaving);
  RETURN NULL;
END $$;
CREATE TRIGGER bf_batch_counts_on_link_insert AFTER INSERT ON batch_jobs
  REFERENCING NEW TABLE AS new_links FOR EACH STATEMENT EXECUTE FUNCTION bf_batch_counts_on_links();
CREATE TRIGGER bf_batch_counts_on_link_update AFTER UPDATE ON batch_jobs
  REFERENCING OLD TABLE AS old_links NEW TABLE AS new_links
  FOR EACH STATEMENT EXECUTE FUNCTION bf_batch_counts_on_links();
CREATE TRIGGER bf_batch_counts_on_link_delete AFTER DELETE ON batch_jobs
  REFERENCING OLD TABLE AS old_links FOR EACH STATEMENT EXECUTE FUNCTION bf_batch_counts_on_links();
"""

_DROP = """
DROP TRIGGER IF EXISTS bf_batch_counts_on_link_delete ON batch_jobs;
DROP TRIGGER IF EXISTS bf_batch_counts_on_link_update ON batch_jobs;
DROP TRIGGER IF EXISTS bf_batch_counts_on_link_insert ON batch_jobs;
DROP TRIGGER IF EXISTS bf_batch_counts_on_jobs ON jobs;
DROP FUNCTION IF EXISTS bf_batch_counts_on_links();
DROP FUNCTION IF EXISTS bf_batch_counts_on_jobs();
DROP FUNCTION IF EXISTS bf_apply_batch_deltas(jsonb);
"""


def upgrade() -> None:
    op.create_table(
        "batch_jobs",
        sa.Column("batch_id", sa.String(length=40), nullable=False),
        sa.Column("position", sa.Integer(), nullable=False),
        sa.Column("job_id", sa.String(length=40), nullable=False),
        sa.ForeignKeyConstraint(
            ["batch_id"], ["batches.id"], name=op.f("fk_batch_jobs_batch_id_batches"), ondelete="CASCADE"
        ),
        sa.ForeignKeyConstraint(["job_id"], ["jobs.id"], name=op.f("fk_batch_jobs_job_id_jobs")),
        sa.PrimaryKeyConstraint("batch_id", "position", name=op.f("pk_batch_jobs")),
    )
    op.create_index(op.f("ix_batch_jobs_job_id"), "batch_jobs", ["job_id"], unique=False)
    for name in COUNT_COLUMNS:
        op.add_column("batches", sa.Column(name, sa.Integer(), server_default="0", nullable=False))
    op.add_column("batches", sa.Column("active_progress", sa.Double(), server_default="0", nullable=False))
    op.create_index(op.f("ix_jobs_retry_of"), "jobs", ["retry_of"], unique=False)

    # the lists of revision 0002 as rows (before the triggers: the counts are computed once below)
    op.execute(
        "INSERT INTO batch_jobs (batch_id, position, job_id) "
        "SELECT b.id, t.ord - 1, t.job_id FROM batches b, "
        "jsonb_array_elements_text(b.job_ids) WITH ORDINALITY AS t(job_id, ord) "
        "WHERE EXISTS (SELECT 1 FROM jobs j WHERE j.id = t.job_id)"
    )
    op.execute(
        "UPDATE jobs j SET retry_of = r.key FROM batches b, jsonb_each_text(b.retried) AS r "
        "WHERE j.id = r.value AND j.retry_of IS NULL"
    )
    op.execute(
        "UPDATE batches b SET "
        + ", ".join(f"{s} = c.{s}" for s in COUNT_COLUMNS)
        + ", active_progress = c.progress FROM (SELECT bj.batch_id, "
        + ", ".join(f"count(*) FILTER (WHERE j.state = '{s}') AS {s}" for s in COUNT_COLUMNS)
        + ", coalesce(sum(j.progress) FILTER (WHERE j.state IN ('queued', 'running')), 0) AS progress "
        "FROM batch_jobs bj JOIN jobs j ON j.id = bj.job_id GROUP BY bj.batch_id) c WHERE b.id = c.batch_id"
    )
    op.drop_column("batches", "retried")
    op.drop_column("batches", "job_ids")
    op.execute(_APPLY)
    op.execute(_JOBS_TRIGGER)
    op.execute(_LINK_TRIGGERS)


def downgrade() -> None:
    op.execute(_DROP)
    op.add_column("batches", sa.Column("job_ids", _DOCUMENT, server_default=sa.text("'[]'"), nullable=False))
    op.add_column("batches", sa.Column("retried", _DOCUMENT, server_default=sa.text("'{}'"), nullable=False))
    op.execute(
        "UPDATE batches b SET job_ids = l.ids FROM (SELECT batch_id, jsonb_agg(job_id ORDER BY position) AS ids "
        "FROM batch_jobs GROUP BY batch_id) l WHERE b.id = l.batch_id"
    )
    op.execute(
        "UPDATE batches b SET retried = r.m FROM (SELECT bj.batch_id, jsonb_object_agg(j.retry_of, j.id) AS m "
        "FROM batch_jobs bj JOIN jobs j ON j.id = bj.job_id WHERE j.retry_of IS NOT NULL "
        "GROUP BY bj.batch_id) r WHERE b.id = r.batch_id"
    )
    op.drop_index(op.f("ix_jobs_retry_of"), table_name="jobs")
    op.drop_column("batches", "active_progress")
    for name in COUNT_COLUMNS:
        op.drop_column("batches", name)
    op.drop_index(op.f("ix_batch_jobs_job_id"), table_name="batch_jobs")
    op.drop_table("batch_jobs")
