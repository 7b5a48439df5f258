"""The statements of `records.answers` on a real PostgreSQL: a job's rows replaced (written twice,
stored once), removed with their scene or their job, paged by key in a stable order, the fleet's
latest job per scene, task matching with LIKE's wildcards taken literally, the backfill's list."""

from __future__ import annotations

import csv
import io
import json
from datetime import UTC, datetime, timedelta

from sqlalchemy import Engine, delete, func, insert, select

from bayesian_fields_service.records import answers as records
from bayesian_fields_service.records.tables import answers, batch_jobs, batches, jobs

T0 = datetime(2026, 1, 1, tzinfo=UTC)


def _job(db: Engine, job_id: str, scene: str, *, tenant: str = "t1", batch: str | None = None,
         position: int = 0, state: str = "succeeded") -> None:  # fmt: skip
    with db.begin() as conn:
        if batch and conn.execute(select(batches.c.id).where(batches.c.id == batch)).first() is None:
            conn.execute(insert(batches).values(id=batch, tenant=tenant, priority="bulk", job_count=0))
        conn.execute(insert(jobs).values(id=job_id, tenant=tenant, scene_id=scene, batch_id=batch, state=state,
                                         priority="bulk", tasks=["mug"], model_profile="p"))  # fmt: skip
        if batch:
            conn.execute(insert(batch_jobs).values(batch_id=batch, position=position, job_id=job_id))


def _rows(job_id: str, scene: str, probs: list[float], *, task: str = "mug", tenant: str = "t1",
          finished: datetime = T0) -> list[dict]:  # fmt: skip
    base = {"job_id": job_id, "tenant": tenant, "scene_id": scene, "finished_at": finished, "task": task,
            "task_index": 0}  # fmt: skip
    if not probs:
        return [{**base, "rank": 0, "found": False, "not_found_reason": "too little evidence"}]
    return [
        {**base, "rank": i + 1, "found": True, "object_id": i, "probability": p} for i, p in enumerate(probs)
    ]


def _write(db: Engine, job_id: str, rows: list[dict]) -> None:
    with db.begin() as conn:
        records.replace_job(conn, job_id, rows)


def _count(db: Engine, **where: str) -> int:
    with db.connect() as conn:
        query = select(func.count()).select_from(answers)
        for k, v in where.items():
            query = query.where(answers.c[k] == v)
        return int(conn.execute(query).scalar_one())


def test_a_job_written_twice_holds_its_rows_once(records_db: Engine) -> None:
    _job(records_db, "j1", "s1")
    _write(records_db, "j1", _rows("j1", "s1", [0.9, 0.5]) + _rows("j1", "s1", [], task="cat")[:0])
    _write(records_db, "j1", _rows("j1", "s1", [0.9, 0.5]))
    assert _count(records_db, job_id="j1") == 2
    _write(records_db, "j1", _rows("j1", "s1", []))  # one shape for found and not-found rows
    assert _count(records_db, job_id="j1") == 1


def test_a_scenes_delete_and_a_jobs_delete_remove_their_answers(records_db: Engine) -> None:
    for job, scene in (("j1", "s1"), ("j2", "s2"), ("j3", "s1")):
        _job(records_db, job, scene)
        _write(records_db, job, _rows(job, scene, [0.7]))
    with records_db.begin() as conn:
        assert records.delete_scene(conn, "t1", "s1") == 2
        assert records.delete_scene(conn, "other-tenant", "s2") == 0
    assert _count(records_db) == 1
    with records_db.begin() as conn:
        conn.execute(delete(jobs).where(jobs.c.id == "j2"))
    assert _count(records_db) == 0


def test_batch_pages_follow_submission_order_and_never_repeat(records_db: Engine) -> None:
    for pos in range(5):
        _job(records_db, f"j{pos}", f"s{pos}", batch="b1", position=pos)
        _write(records_db, f"j{pos}", _rows(f"j{pos}", f"s{pos}", [0.9, 0.6, 0.3] if pos % 2 else []))
    _job(records_db, "jx", "sx", tenant="t2", batch="b2")
    _write(records_db, "jx", _rows("jx", "sx", [0.99], tenant="t2"))
    wanted = records.AnswerFilter()
    whole = records.batch_page(records_db, "t1", "b1", wanted, after=None, limit=100)
    assert [(r["job_id"], r["rank"]) for r in whole] == [
        ("j0", 0), ("j1", 1), ("j1", 2), ("j1", 3), ("j2", 0), ("j3", 1), ("j3", 2), ("j3", 3), ("j4", 0)]  # fmt: skip
    paged, after = [], None
    while page := records.batch_page(records_db, "t1", "b1", wanted, after=after, limit=2):
        paged += page
        after = (page[-1]["position"], page[-1]["task_index"], page[-1]["rank"])
    assert paged == whole
    assert records.batch_page(records_db, "t2", "b1", wanted, after=None, limit=100) == []  # another tenant
    sure = records.batch_page(records_db, "t1", "b1", records.AnswerFilter(min_probability=0.5, max_rank=1),
                              after=None, limit=100)  # fmt: skip
    assert [(r["job_id"], r["rank"]) for r in sure] == [("j1", 1), ("j3", 1)]
    missing = records.batch_page(
        records_db, "t1", "b1", records.AnswerFilter(found=False), after=None, limit=100
    )
    assert [r["job_id"] for r in missing] == ["j0", "j2", "j4"]


def _parsed(chunks: list[bytes]) -> list[dict]:
    text = b"".join(chunks).decode()
    return list(csv.DictReader(io.StringIO(",".join(records.COLUMNS) + "\n" + text)))


def _as_csv_cells(row: dict) -> dict:
    """A listed row as its CSV cells, parsed back: None empty, numbers as numbers."""
    return {c: "" if row.get(c) is None else str(row[c]) for c in records.COLUMNS}


def test_the_batch_csv_is_the_listing_written_by_the_database(records_db: Engine) -> None:
    """`batch_csv` (COPY, pages of jobs) gives the rows `batch_page` lists, in its order, from a
    cursor and with filters, for any page size; quotes and commas in a task survive CSV."""
    task = 'the "big", red mug'
    for pos in range(7):
        _job(records_db, f"j{pos}", f"s{pos}", batch="b1", position=pos)
        rows = _rows(f"j{pos}", f"s{pos}", [0.9, 0.625, 0.25] if pos % 3 else [], task=task)
        for r in rows:
            if r["found"]:
                r.update(rotation=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], centre_x=-1.5)
        _write(records_db, f"j{pos}", rows)
    _job(records_db, "jx", "sx", tenant="t2", batch="b1", position=7)  # another tenant's row: never shown
    _write(records_db, "jx", _rows("jx", "sx", [0.99], tenant="t2"))
    wanted = records.AnswerFilter()
    listed = records.batch_page(records_db, "t1", "b1", wanted, after=None, limit=100)
    for per_page in (1, 2, 50):
        got = _parsed(
            list(records.batch_csv(records_db, "t1", "b1", wanted, after=None, jobs_per_page=per_page))
        )
        assert [(r["job_id"], int(r["rank"])) for r in got] == [(r["job_id"], r["rank"]) for r in listed]
    by_key = {(r["job_id"], int(r["rank"])): r for r in got}
    for row in listed:
        cells = by_key[(row["job_id"], row["rank"])]
        assert cells["task"] == task and cells["found"] == str(row["found"])
        for name in ("probability", "centre_x"):
            assert (float(cells[name]) if cells[name] else None) == row[name]
        assert (json.loads(cells["rotation"]) if cells["rotation"] else None) == row["rotation"]
        assert " " not in cells["rotation"]
    after = (listed[3]["position"], listed[3]["task_index"], listed[3]["rank"])
    rest = _parsed(list(records.batch_csv(records_db, "t1", "b1", wanted, after=after, jobs_per_page=2)))
    assert [(r["job_id"], int(r["rank"])) for r in rest] == [(r["job_id"], r["rank"]) for r in listed[4:]]
    sure = records.AnswerFilter(min_probability=0.5, max_rank=1, task=task)
    kept = _parsed(list(records.batch_csv(records_db, "t1", "b1", sure, after=None, jobs_per_page=3)))
    assert [r["job_id"] for r in kept] == ["j1", "j2", "j4", "j5"]
    hostile = records.AnswerFilter(scene="'); DROP TABLE answers; --")
    assert list(records.batch_csv(records_db, "t1", "b1", hostile, after=None, jobs_per_page=3)) == []
    assert _count(records_db) == 4 * 3 + 3 + 1  # nothing dropped
    assert list(records.batch_csv(records_db, "t2", "nope", wanted, after=None, jobs_per_page=3)) == []


def test_the_fleet_takes_each_scenes_latest_job_and_counts_the_misses(records_db: Engine) -> None:
    plan = [("j1", "s1", [0.2], 0), ("j2", "s1", [0.8, 0.4], 1), ("j3", "s2", [0.6], 0), ("j4", "s3", [], 0),
            ("j5", "s4", [0.95], 0), ("j6", "s4", [], 2)]  # fmt: skip
    for job, scene, probs, day in plan:
        _job(records_db, job, scene)
        _write(records_db, job, _rows(job, scene, probs, finished=T0 + timedelta(days=day)))
    got = records.fleet(records_db, "t1", "mug", limit=10)
    assert [(r["job_id"], r["rank"]) for r in got.rows] == [("j2", 1), ("j3", 1)]  # s3, s4: latest not found
    assert (got.asked, got.not_found) == (4, 2)
    every = records.fleet(records_db, "t1", "mug", best_only=False, limit=10)
    assert [(r["job_id"], r["rank"]) for r in every.rows] == [("j2", 1), ("j3", 1), ("j2", 2)]
    first = records.fleet(records_db, "t1", "mug", best_only=False, limit=1).rows[0]
    rest = records.fleet(
        records_db, "t1", "mug", best_only=False, after=(first["probability"], "j2", 1), limit=10
    )
    assert [(r["job_id"], r["rank"]) for r in rest.rows] == [("j3", 1), ("j2", 2)]
    assert records.fleet(records_db, "t2", "mug", limit=10).asked == 0


def test_task_parts_match_literally(records_db: Engine) -> None:
    _job(records_db, "j1", "s1")
    _write(records_db, "j1", _rows("j1", "s1", [0.5], task="the 100% mug") + [
        {**_rows("j1", "s1", [0.5], task="a_cup")[0], "task_index": 1}])  # fmt: skip
    assert records.matching_tasks(records_db, "t1", "100%") == ["the 100% mug"]
    assert records.matching_tasks(records_db, "t1", "MUG") == ["the 100% mug"]
    assert records.matching_tasks(records_db, "t1", "%") == ["the 100% mug"]
    assert records.matching_tasks(records_db, "t1", "_") == ["a_cup"]
    assert records.matching_tasks(records_db, "t1", "a_cup") == ["a_cup"]
    assert records.matching_tasks(records_db, "t2", "mug") == []


def test_the_backfill_lists_succeeded_jobs_without_answers(records_db: Engine) -> None:
    _job(records_db, "j1", "s1")
    _job(records_db, "j2", "s1")
    _job(records_db, "j3", "s1", state="failed")
    _write(records_db, "j1", _rows("j1", "s1", [0.5]))
    assert [j for _, j, _, _ in records.unindexed_jobs(records_db, limit=10)] == ["j2"]
    assert records.count_unindexed(records_db) == 1
    records.write_job(records_db, "j3", _rows("j3", "s1", [0.5]))  # not succeeded: nothing written
    assert _count(records_db, job_id="j3") == 0
