"""The statements of the `answers` table (issue 42): a succeeded job's answers written with its
success, a scene's removed with its delete, a batch's paged in a stable order, a tenant's fleet
searched for one task, and the backfill's list of succeeded jobs without answers.

Why keyset paging everywhere (also for the streamed export): a page is one indexed range read
whatever the batch's size, and an export is a loop of such pages, so the API's memory stays that
of one page and no connection is held between pages (an OFFSET or a long-lived server-side cursor
would cost either the batch's size in time or a connection for the export's duration).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from sqlalchemy import (
    Connection,
    Engine,
    Text,
    and_,
    case,
    cast,
    delete,
    func,
    insert,
    literal,
    or_,
    select,
    tuple_,
)
from sqlalchemy.dialects.postgresql import distinct_on
from sqlalchemy.sql import Select

from bayesian_fields_service.records.tables import answers, batch_jobs, jobs, scenes

#: The columns every answer listing returns, in this order (the CSV header; `answers_format`).
COLUMNS: tuple[str, ...] = (
    "job_id", "scene_id", "scene_name", "task", "task_index", "rank", "found", "object_id",
    "content_key", "probability", "best_view_score", "score", "ranked_by", "num_gaussians", "frame",
    "centre_x", "centre_y", "centre_z", "extent_x", "extent_y", "extent_z", "rotation",
    "centroid_x", "centroid_y", "centroid_z", "preview", "not_found_reason",
)  # fmt: skip


@dataclass(frozen=True)
class AnswerFilter:
    """What a listing keeps: one task's exact text (resolved by `matching_tasks`), a least
    probability, a greatest rank, found or not, one scene (by name or id)."""

    task: str | None = None
    min_probability: float | None = None
    max_rank: int | None = None
    found: bool | None = None
    scene: str | None = None


def replace_job(conn: Connection, job_id: str, rows: Sequence[dict[str, Any]]) -> None:
    """The job's answers become `rows` (its earlier rows deleted first): a repeated finish or a
    backfill run twice writes them once. Inside the caller's transaction."""
    conn.execute(delete(answers).where(answers.c.job_id == job_id))
    if rows:  # every row with every column: one executemany needs one shape ("not found" rows hold few)
        names = [c.name for c in answers.columns]
        conn.execute(insert(answers), [{n: row.get(n) for n in names} for row in rows])


def delete_scene(conn: Connection, tenant: str, scene_id: str) -> int:
    """Remove every answer of the scene's jobs (a scene's delete; jobs keep no key to scenes)."""
    done = conn.execute(delete(answers).where(answers.c.tenant == tenant, answers.c.scene_id == scene_id))
    return int(done.rowcount or 0)


def _columns(position: Any) -> list[Any]:
    named = [answers.c[c] for c in COLUMNS if c not in ("scene_name",)]
    return [*named, scenes.c.name.label("scene_name"), position.label("position")]


def _filtered(query: Select, wanted: AnswerFilter) -> Select:
    if wanted.task is not None:
        query = query.where(answers.c.task == wanted.task)
    if wanted.min_probability is not None:
        query = query.where(answers.c.probability >= wanted.min_probability)
    if wanted.max_rank is not None:
        query = query.where(answers.c.rank <= wanted.max_rank)
    if wanted.found is not None:
        query = query.where(answers.c.found.is_(wanted.found))
    if wanted.scene is not None:
        query = query.where(or_(scenes.c.name == wanted.scene, answers.c.scene_id == wanted.scene))
    return query


def batch_page(
    database: Engine,
    tenant: str,
    batch_id: str,
    wanted: AnswerFilter,
    *,
    after: tuple[int, int, int] | None,
    limit: int,
) -> list[dict[str, Any]]:
    """Up to `limit` answers of the batch's jobs after the key `after` = (position in the batch,
    task index, rank), in that order (the batch's submission order, then each job's tasks and
    ranks): stable while jobs finish, since a row's key never changes."""
    query = _batch_rows(tenant, batch_id, wanted, _columns(batch_jobs.c.position))
    if after is not None:
        # The row-value comparison spans two tables, so it cannot bound an index scan by itself:
        # without the first column's own bound every page re-read the batch from its first job
        # (an export was quadratic in the batch's size: bench/bench_answers.py).
        key = tuple_(batch_jobs.c.position, answers.c.task_index, answers.c.rank)
        query = query.where(batch_jobs.c.position >= after[0], key > tuple_(*(literal(v) for v in after)))
    query = query.limit(limit)
    with database.connect() as conn:
        return [dict(r) for r in conn.execute(query).mappings()]


def _batch_rows(tenant: str, batch_id: str, wanted: AnswerFilter, columns: Sequence[Any]) -> Select:
    """`columns` of the batch's answers kept by `wanted`, in the batch's order (no page bounds)."""
    query = (
        select(*columns)
        .select_from(
            batch_jobs.join(answers, answers.c.job_id == batch_jobs.c.job_id).outerjoin(
                scenes, and_(scenes.c.id == answers.c.scene_id, scenes.c.tenant == answers.c.tenant)
            )
        )
        .where(batch_jobs.c.batch_id == batch_id, answers.c.tenant == tenant)
    )
    return _filtered(query, wanted).order_by(batch_jobs.c.position, answers.c.task_index, answers.c.rank)


def _csv_cells() -> list[Any]:
    """`COLUMNS` as PostgreSQL writes them into CSV: found as True / False (as Python writes
    them), the rotation as compact JSON (it holds only numbers, so no space is data)."""
    cells: list[Any] = []
    for name in COLUMNS:
        if name == "scene_name":
            cells.append(scenes.c.name)
        elif name == "found":
            cells.append(case((answers.c.found, literal("True")), else_=literal("False")))
        elif name == "rotation":
            cells.append(func.replace(cast(answers.c.rotation, Text), " ", ""))
        else:
            cells.append(answers.c[name])
    return cells


def batch_csv(
    database: Engine,
    tenant: str,
    batch_id: str,
    wanted: AnswerFilter,
    *,
    after: tuple[int, int, int] | None,
    jobs_per_page: int,
) -> Iterator[bytes]:
    """The CSV lines (no header) of every answer `batch_page` would list after `after`, written
    by PostgreSQL (`COPY ... TO STDOUT`), `jobs_per_page` of the batch's jobs at a time.

    Why COPY: formatting two million rows in the API process took minutes of its CPU and the
    other tenants' requests waited on it (bench/bench_answers.py); the server writes CSV at
    several times the speed, and the API only passes the bytes on. Why pages of jobs: each is a
    range of the batch's positions (an indexed read whatever the batch's size), read whole into
    memory (a few MB) with the connection given back before its bytes are sent, so a slow client
    holds no connection and the API's memory is one page's."""
    low = after[0] if after is not None else 0
    while True:
        bound = (
            select(batch_jobs.c.position)
            .where(batch_jobs.c.batch_id == batch_id, batch_jobs.c.position >= low)
            .order_by(batch_jobs.c.position)
            .offset(jobs_per_page)
            .limit(1)
        )
        with database.connect() as conn:
            high = conn.execute(bound).scalar_one_or_none()
            query = _batch_rows(tenant, batch_id, wanted, _csv_cells()).where(batch_jobs.c.position >= low)
            if high is not None:
                query = query.where(batch_jobs.c.position < high)
            if after is not None:
                key = tuple_(batch_jobs.c.position, answers.c.task_index, answers.c.rank)
                query = query.where(key > tuple_(*(literal(v) for v in after)))
            compiled = query.compile(dialect=conn.dialect, compile_kwargs={"render_postcompile": True})
            raw = conn.connection.driver_connection
            assert raw is not None
            with raw.cursor() as cursor:
                statement = f"COPY ({compiled.string}) TO STDOUT WITH (FORMAT csv)"
                with cursor.copy(statement, compiled.params) as copy:
                    chunk = b"".join(bytes(data) for data in copy)
            conn.rollback()
        if chunk:
            yield chunk
        if high is None:
            return
        low = high


def matching_tasks(database: Engine, tenant: str, part: str, *, batch_id: str | None = None) -> list[str]:
    """The answered tasks named `part`: its exact text if any answer has it, else the tasks whose
    text contains it (case-insensitive; at most a few, enough to say "several")."""
    scope = select(answers.c.task).where(answers.c.tenant == tenant)
    if batch_id is not None:
        scope = scope.where(
            answers.c.job_id.in_(select(batch_jobs.c.job_id).where(batch_jobs.c.batch_id == batch_id))
        )
    with database.connect() as conn:
        if conn.execute(scope.where(answers.c.task == part).limit(1)).first() is not None:
            return [part]
        escaped = part.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")
        like = scope.where(answers.c.task.ilike(f"%{escaped}%", escape="\\")).distinct().limit(10)
        return sorted(r.task for r in conn.execute(like))


@dataclass(frozen=True)
class FleetAnswers:
    """A fleet search's page: `rows` ranked by probability, `asked` the scenes whose latest
    succeeded job asked the task, `not_found` how many of those answered it "not found"."""

    rows: list[dict[str, Any]]
    asked: int
    not_found: int


def _ranked(
    query: Select, c: Any, min_probability: float | None, after: tuple[float, str, int] | None, limit: int
) -> Select:
    """`query` ranked by `c.probability` (then job id and rank), from `min_probability` up, after
    the keyset `after`, `limit` rows."""
    if min_probability is not None:
        query = query.where(c.probability >= min_probability)
    if after is not None:
        p, job, rank = after
        query = query.where(
            or_(
                c.probability < p,
                and_(c.probability == p, tuple_(c.job_id, c.rank) > tuple_(literal(job), literal(rank))),
            )
        )
    return query.order_by(c.probability.desc(), c.job_id, c.rank).limit(limit)


def fleet(
    database: Engine,
    tenant: str,
    task: str,
    *,
    batch_ids: Sequence[str] = (),
    min_probability: float | None = None,
    best_only: bool = True,
    after: tuple[float, str, int] | None = None,
    limit: int,
) -> FleetAnswers:
    """The answers to `task` of each scene's latest succeeded job that asked it (within
    `batch_ids` when given), found ones ranked by probability (then job id and rank: a total
    order for the keyset `after` = (probability, job id, rank)); with `best_only` each scene's
    best row only."""
    # Each job that asked the task has one row of rank <= 1 (its best object, or its "not found"
    # row): the partial index `ix_answers_latest` holds just those, with what the ranking needs
    # (INCLUDE), in the order DISTINCT ON reads them backwards (a scene's newest job first). So
    # "each scene's latest job" is one index-only scan of an entry per job, and each scene's best
    # answer is that entry: only the page's rows are read from the table.
    asked = select(
        answers.c.job_id, answers.c.scene_id, answers.c.task_index, answers.c.rank, answers.c.found,
        answers.c.probability,
    ).where(answers.c.tenant == tenant, answers.c.task == task, answers.c.rank <= 1)  # fmt: skip
    if batch_ids:
        asked = asked.where(
            answers.c.job_id.in_(
                select(batch_jobs.c.job_id).where(batch_jobs.c.batch_id.in_(list(batch_ids)))
            )
        )
    latest = (
        asked.ext(distinct_on(answers.c.scene_id))
        .order_by(answers.c.scene_id.desc(), answers.c.finished_at.desc(), answers.c.job_id.desc())
        .cte("latest")
    )
    named = scenes, and_(scenes.c.id == answers.c.scene_id, scenes.c.tenant == answers.c.tenant)
    if best_only:
        top = _ranked(select(latest.c.job_id, latest.c.task_index, latest.c.rank), latest.c, min_probability,
                      after, limit).where(latest.c.found.is_(True)).subquery("top")  # fmt: skip
        chosen = answers.join(top, and_(answers.c.job_id == top.c.job_id, answers.c.task_index == top.c.task_index,
                                        answers.c.rank == top.c.rank))  # fmt: skip
        query = (
            select(*_columns(literal(0)))
            .select_from(chosen.outerjoin(*named))
            .order_by(answers.c.probability.desc(), answers.c.job_id, answers.c.rank)
        )
    else:  # every ranked object of those jobs' answers to the task (its index in each job)
        chosen = answers.join(
            latest, and_(latest.c.job_id == answers.c.job_id, latest.c.task_index == answers.c.task_index)
        )
        query = _ranked(
            select(*_columns(literal(0))).select_from(chosen.outerjoin(*named)), answers.c, min_probability,
            after, limit,
        ).where(answers.c.found.is_(True))  # fmt: skip
    counts = select(func.count(), func.count().filter(latest.c.found.is_(False))).select_from(latest)
    with database.connect() as conn:
        rows = [dict(r) for r in conn.execute(query).mappings()]
        total, missing = conn.execute(counts).one()
    return FleetAnswers(rows, int(total), int(missing))


def unindexed_jobs(database: Engine, *, after: str = "", limit: int) -> list[tuple[str, str, str, Any]]:
    """Up to `limit` succeeded jobs (tenant, id, scene, finished_at) with no answer rows, by id
    after `after`: the backfill's next batch (resumable: an indexed job never shows again)."""
    query = (
        select(jobs.c.tenant, jobs.c.id, jobs.c.scene_id, jobs.c.finished_at)
        .where(
            jobs.c.state == "succeeded",
            jobs.c.id > after,
            ~select(answers.c.job_id).where(answers.c.job_id == jobs.c.id).exists(),
        )
        .order_by(jobs.c.id)
        .limit(limit)
    )
    with database.connect() as conn:
        return [(r.tenant, r.id, r.scene_id, r.finished_at) for r in conn.execute(query)]


def count_unindexed(database: Engine) -> int:
    """How many succeeded jobs have no answer rows yet (the backfill's progress total)."""
    query = select(func.count()).where(
        jobs.c.state == "succeeded",
        ~select(answers.c.job_id).where(answers.c.job_id == jobs.c.id).exists(),
    )
    with database.connect() as conn:
        return int(conn.execute(query).scalar_one())


def write_job(database: Engine, job_id: str, rows: Sequence[dict[str, Any]]) -> None:
    """`replace_job` in a transaction of its own, only while the job is still succeeded (the
    backfill: a job deleted or changed meanwhile gets no rows)."""
    with database.begin() as conn:
        alive = conn.execute(
            select(jobs.c.id).where(jobs.c.id == job_id, jobs.c.state == "succeeded").with_for_update()
        ).first()
        if alive is not None:
            replace_job(conn, job_id, rows)


def answer_probability(database: Engine, tenant: str, task: str, job_id: str, rank: int) -> float | None:
    """The probability of one found answer (a fleet cursor's position), or None when it is gone."""
    query = select(answers.c.probability).where(
        answers.c.tenant == tenant, answers.c.job_id == job_id, answers.c.task == task,
        answers.c.rank == rank, answers.c.found.is_(True),
    )  # fmt: skip
    with database.connect() as conn:
        return conn.execute(query).scalar_one_or_none()
