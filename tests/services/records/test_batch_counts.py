"""A batch's counts are kept by the database (migration 0003's triggers): after any sequence of
job changes (one row, many rows in one statement, the batch cancel statement, a retry replacing
a job in its slot, a job shared by two batches) every batch row equals a recount of its jobs.
Also: revision 0002's job lists and retried maps become rows and come back on downgrade, and
`finished_batches` marks a batch once."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sqlalchemy import Connection, Engine, func, insert, select, text, update

from bayesian_fields_service.jobs.batches import BatchRecord, batch_of_row
from bayesian_fields_service.records import batches as batch_rows
from bayesian_fields_service.records.database import engine, migrate
from bayesian_fields_service.records.tables import JOB_STATES, batch_jobs, batches, jobs
from tests.integration.fixtures.postgres import records_database

STATES = st.sampled_from(JOB_STATES)


def _insert_batch(conn: Connection, batch: BatchRecord, job_count: int) -> None:
    batch_rows.insert_row(conn, id=batch.id, tenant=batch.tenant, priority=batch.priority,
                          callback_url=batch.callback_url, job_count=job_count, idempotency_key=None)  # fmt: skip


def _finished_batches(conn: Connection, job_ids: list[str]) -> list[BatchRecord]:
    return [batch_of_row(r) for r in batch_rows.mark_finished(conn, job_ids)]


@pytest.fixture(scope="module")
def db() -> Iterator[Engine]:
    with records_database() as records:
        yield records


def _job(job_id: str, batch_id: str | None, state: str = "queued", progress: float = 0.0) -> dict:
    return {"id": job_id, "tenant": "t", "scene_id": "s_x", "batch_id": batch_id, "state": state,
            "priority": "bulk", "tasks": ["a"], "model_profile": "default", "progress": progress}  # fmt: skip


def _recount(conn, batch_id: str) -> dict[str, float]:  # noqa: ANN001
    rows = conn.execute(
        select(jobs.c.state, func.count(), func.coalesce(func.sum(jobs.c.progress), 0))
        .join(batch_jobs, batch_jobs.c.job_id == jobs.c.id)
        .where(batch_jobs.c.batch_id == batch_id)
        .group_by(jobs.c.state)
    ).all()
    out: dict[str, float] = {s: 0 for s in JOB_STATES}
    progress = 0.0
    for state, n, p in rows:
        out[state] = n
        if state in ("queued", "running"):
            progress += p
    out["active_progress"] = round(progress, 6)
    return out


def _stored(conn, batch_id: str) -> dict[str, float]:  # noqa: ANN001
    row = conn.execute(select(batches).where(batches.c.id == batch_id)).mappings().one()
    return {**{s: row[s] for s in JOB_STATES}, "active_progress": round(row["active_progress"], 6)}


CHANGE = st.one_of(
    st.tuples(st.just("one"), st.integers(0, 11), STATES, st.floats(0, 100)),
    st.tuples(st.just("many"), st.integers(0, 11), STATES, st.floats(0, 100)),
    st.tuples(st.just("cancel"), st.integers(0, 1), st.just(""), st.just(0.0)),
    st.tuples(st.just("retry"), st.integers(0, 11), STATES, st.just(0.0)),
)


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck), database=None)
@given(changes=st.lists(CHANGE, min_size=1, max_size=12), seed=st.integers(0, 10**9))
@pytest.mark.slow
def test_counts_equal_a_recount_after_any_changes(db: Engine, changes: list, seed: int) -> None:
    ids = [f"j_{seed}_{i}" for i in range(12)]
    b0, b1 = f"b_{seed}_0", f"b_{seed}_1"
    with db.begin() as conn:
        conn.execute(text("DELETE FROM batch_jobs; DELETE FROM jobs; DELETE FROM batches"))
        for b in (b0, b1):
            _insert_batch(conn, BatchRecord(id=b, tenant="t"), 8)
        conn.execute(insert(jobs), [_job(j, b0 if i < 8 else b1) for i, j in enumerate(ids)])
        batch_rows.insert_links(conn, b0, ids[:8])
        batch_rows.insert_links(conn, b1, ids[8:] + ids[2:6])  # four jobs in both batches
    retries = 0
    for kind, at, state, progress in changes:
        with db.begin() as conn:
            if kind == "one":
                conn.execute(update(jobs).where(jobs.c.id == ids[at]).values(state=state, progress=progress))
            elif kind == "many":  # one statement over many rows
                conn.execute(
                    update(jobs).where(jobs.c.id.in_(ids[: at + 1])).values(state=state, progress=progress)
                )
            elif kind == "cancel":
                batch_rows.cancel_jobs(conn, "t", (b0, b1)[at])
            else:  # a retry: a new job takes the slot of ids[at] in every batch that holds it
                retries += 1
                new = f"{ids[at]}_r{retries}"
                conn.execute(insert(jobs), [_job(new, b0, state)])
                holders = [
                    r.batch_id
                    for r in conn.execute(select(batch_jobs.c.batch_id).where(batch_jobs.c.job_id == ids[at]))
                ]
                for holder in holders:
                    batch_rows.replace_jobs(conn, holder, {ids[at]: new})
                ids[at] = new
        with db.connect() as conn:
            for b in (b0, b1):
                assert _stored(conn, b) == _recount(conn, b), (kind, at, state)


def test_finished_batches_marks_a_batch_once_per_finish(db: Engine) -> None:
    with db.begin() as conn:
        conn.execute(text("DELETE FROM batch_jobs; DELETE FROM jobs; DELETE FROM batches"))
        _insert_batch(conn, BatchRecord(id="b_f", tenant="t", callback_url="https://x.test/"), 2)
        conn.execute(insert(jobs), [_job("j_f1", "b_f"), _job("j_f2", "b_f")])
        batch_rows.insert_links(conn, "b_f", ["j_f1", "j_f2"])
    with db.begin() as conn:
        conn.execute(update(jobs).where(jobs.c.id == "j_f1").values(state="succeeded"))
        assert _finished_batches(conn, ["j_f1"]) == []  # j_f2 still waits
    with db.begin() as conn:
        conn.execute(update(jobs).where(jobs.c.id == "j_f2").values(state="failed"))
        (done,) = _finished_batches(conn, ["j_f2"])
        assert done.counts == {**dict.fromkeys(JOB_STATES, 0), "succeeded": 1, "failed": 1}
        assert done.finished_at is not None and done.total == 2
    with db.begin() as conn:  # a late duplicate of the same end marks nothing
        assert _finished_batches(conn, ["j_f1", "j_f2"]) == []
    with db.begin() as conn:  # a retry opens the batch again; its end is a new finish
        conn.execute(insert(jobs), [_job("j_f3", "b_f")])
        batch_rows.replace_jobs(conn, "b_f", {"j_f2": "j_f3"})
        assert _finished_batches(conn, ["j_f3"]) == []
        conn.execute(update(jobs).where(jobs.c.id == "j_f3").values(state="succeeded"))
        (again,) = _finished_batches(conn, ["j_f3"])
        assert again.counts["succeeded"] == 2 and again.counts["failed"] == 0


def test_revision_0002_lists_become_rows_and_come_back(fresh_database: str) -> None:
    migrate(fresh_database, "0002")
    db = engine(fresh_database)
    with db.begin() as conn:
        conn.execute(text(
            "INSERT INTO batches (id, tenant, priority, job_count, job_ids, retried) VALUES "
            "('b_old', 't', 'bulk', 3, '[\"j_a\", \"j_c\", \"j_b\"]', '{\"j_x\": \"j_c\"}')"
        ))  # fmt: skip
        for job_id, state in (("j_a", "succeeded"), ("j_b", "queued"), ("j_c", "running"), ("j_x", "failed")):
            conn.execute(text(
                "INSERT INTO jobs (id, tenant, scene_id, batch_id, state, priority, tasks, model_profile, progress) "
                f"VALUES ('{job_id}', 't', 's_x', 'b_old', '{state}', 'bulk', '[]', 'default', 10)"
            ))  # fmt: skip
    assert migrate(fresh_database, "0003") == "0003"
    with db.connect() as conn:
        links = conn.execute(
            select(batch_jobs.c.position, batch_jobs.c.job_id).order_by(batch_jobs.c.position)
        ).all()
        assert [tuple(r) for r in links] == [(0, "j_a"), (1, "j_c"), (2, "j_b")]
        assert conn.execute(select(jobs.c.retry_of).where(jobs.c.id == "j_c")).scalar_one() == "j_x"
        assert _stored(conn, "b_old") == _recount(conn, "b_old")
        assert _stored(conn, "b_old")["running"] == 1 and _stored(conn, "b_old")["active_progress"] == 20
    assert migrate(fresh_database, "-1") == "0002"
    with db.connect() as conn:
        row = conn.execute(text("SELECT job_ids, retried FROM batches WHERE id = 'b_old'")).one()
    assert row.job_ids == ["j_a", "j_c", "j_b"] and row.retried == {"j_x": "j_c"}
