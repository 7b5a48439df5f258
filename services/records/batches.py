"""The statements over `batches` and `batch_jobs` rows: a batch's row (its per-state counts kept
by the triggers of migration 0003, `records.triggers`), its links in submission order, a page of
its jobs, the cancel of its active jobs, a retry's replacements and the decision that it finished.

Why statements: a batch of 50,000 jobs is submitted with one multi-row INSERT of its jobs and one
of its links, a page is an index range over (batch, position), cancel is one UPDATE, and the
batch's end is decided by the database (`mark_finished`) in the transaction of the change that
ends it. The batch model and its status stay in the domain (`jobs.batches`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy import ARRAY, Connection, RowMapping, and_, case, cast, func, insert, select, text, update

from bayesian_fields_service.records.tables import ACTIVE_JOB_STATES, ID, batch_jobs, batches, jobs

_INSERT_LINKS = text(
    "INSERT INTO batch_jobs (batch_id, position, job_id) SELECT :batch_id, n - 1, job_id "
    "FROM unnest(CAST(:job_ids AS varchar[])) WITH ORDINALITY AS ids(job_id, n)"
)
"""A batch's links numbered in one statement."""


def insert_row(conn: Connection, **row: Any) -> None:
    """The batch's row (its columns by name), before its new jobs, which name it."""
    conn.execute(insert(batches).values(**row))


def insert_links(conn: Connection, batch_id: str, job_ids: Sequence[str]) -> None:
    """The batch's jobs in submission order (after the jobs' rows: the triggers count each job's
    state as it enters)."""
    if job_ids:  # one statement (an executemany would run the count trigger once per row)
        conn.execute(_INSERT_LINKS, {"batch_id": batch_id, "job_ids": list(job_ids)})


def load(conn: Connection, tenant: str, batch_id: str) -> RowMapping | None:
    """The batch's row, or None."""
    query = select(batches).where(batches.c.tenant == tenant, batches.c.id == batch_id)
    return conn.execute(query).mappings().first()


def job_rows(
    conn: Connection, batch_id: str, *, start: int = 0, limit: int | None = None,
    states: Sequence[str] | None = None, job_ids: Sequence[str] | None = None,
) -> list[tuple[int, RowMapping]]:  # fmt: skip
    """(position, jobs row) of a batch's jobs in submission order: the positions `start` to
    `start + limit` (all from `start` without `limit`), only those in `states` / among `job_ids`
    when given. One index range over (batch_id, position)."""
    query = (
        select(batch_jobs.c.position, jobs)
        .join(jobs, jobs.c.id == batch_jobs.c.job_id)
        .where(batch_jobs.c.batch_id == batch_id, batch_jobs.c.position >= start)
        .order_by(batch_jobs.c.position)
    )
    if states is not None:
        query = query.where(jobs.c.state.in_(list(states)))
    if job_ids is not None:
        query = query.where(batch_jobs.c.job_id.in_(list(job_ids)))
    if limit is not None:  # positions are contiguous (a retry takes its job's slot): a closed range
        # reads exactly `limit` links whatever the planner thinks (with ">= start" alone it read
        # and sorted every later link: 100 ms at position 25,000 of 50,000)
        query = query.where(batch_jobs.c.position < start + limit).limit(limit)
    return [(r["position"], r) for r in conn.execute(query).mappings()]


def cancel_jobs(
    conn: Connection, tenant: str, batch_id: str, columns: Sequence[str] | None = None
) -> list[RowMapping]:
    """Accept a cancel for every active job of the batch: a waiting (queued) job is cancelled at
    once, a running one flagged (its worker stops at the next frame or stage and stores
    *cancelled*). Terminal jobs are untouched. Returns the changed rows, only the `columns` named
    (default: all).

    Two statements: the batch's job ids (its index range), then one UPDATE by primary key. The
    single-statement form (IN (subquery) or UPDATE ... FROM batch_jobs) is planned from
    statistics that, right after a batch went in, say "one row": it became a nested loop over the
    whole batch for each job (1.7 s for 5,000). Decoding every JSON column of 5,000 rows took a
    third of a cancel, hence `columns`."""
    ids = list(conn.execute(select(batch_jobs.c.job_id).where(batch_jobs.c.batch_id == batch_id)).scalars())
    if not ids:
        return []
    queued = jobs.c.state == "queued"
    returned = [jobs.c[name] for name in columns] if columns is not None else list(jobs.c)
    statement = (
        update(jobs)
        .where(
            jobs.c.id == func.any(cast(ids, ARRAY(ID))),
            jobs.c.tenant == tenant,
            jobs.c.state.in_(ACTIVE_JOB_STATES),
        )
        .values(
            cancel_requested=True,
            state=func.coalesce(func.nullif(jobs.c.state, "queued"), "cancelled"),
            finished_at=case((queued, func.now()), else_=jobs.c.finished_at),
            error=case((queued, "cancelled by request"), else_=jobs.c.error),
            updated_at=func.now(),
        )
        .returning(*returned)
    )
    return list(conn.execute(statement).mappings())


def replace_jobs(conn: Connection, batch_id: str, new_of: dict[str, str]) -> None:
    """Each old job's slot in the batch takes its new job (a retry); the batch is open again."""
    for old, new in new_of.items():
        conn.execute(
            update(batch_jobs)
            .where(batch_jobs.c.batch_id == batch_id, batch_jobs.c.job_id == old)
            .values(job_id=new)
        )
    conn.execute(
        update(batches).where(batches.c.id == batch_id).values(callback_enqueued=False, finished_at=None)
    )


def mark_finished(conn: Connection, job_ids: Sequence[str]) -> list[RowMapping]:
    """The rows of the batches holding any of `job_ids` that have no active job left and were not
    yet marked finished: marked now (``finished_at``), after the jobs' UPDATE.

    Exactly once per finish: the UPDATE of the batch's counts by the triggers locks its row until
    commit, so of two jobs ending together the second transaction waits and then sees the first
    one's mark."""
    if not job_ids:
        return []
    # one array parameter, not one bound value per job (a 50,000-job cancel ends them all here)
    holding = select(batch_jobs.c.batch_id).where(
        batch_jobs.c.job_id == func.any(cast(list(job_ids), ARRAY(ID)))
    )
    return list(
        conn.execute(
            update(batches)
            .where(
                and_(batches.c.id.in_(holding), batches.c.queued == 0, batches.c.running == 0),
                ~batches.c.callback_enqueued,
            )
            .values(callback_enqueued=True, finished_at=func.now())
            .returning(*batches.c)
        ).mappings()
    )
