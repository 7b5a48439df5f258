"""Recovery's rules, decided from the job's row on a real PostgreSQL (and a private Redis for the
live state it still reads): a job a worker beats is left alone; one whose stages are all done but
whose end was never written is finished, its callback and usage written once; one that lost its
worker is put back in the queue and counted; one that lost it too often fails with the reason."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import redis
from sqlalchemy import Engine, func, select, update

from bayesian_fields_core.job.stage_table import STAGES
from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.control.recovery import Recovery
from bayesian_fields_service.jobs.model import JobRecord, JobState
from bayesian_fields_service.jobs.store import JobStore
from bayesian_fields_service.records import job_heartbeats
from bayesian_fields_service.records.ids import new_id
from bayesian_fields_service.records.tables import callback_outbox, jobs, usage_ledger
from tests.integration.fixtures.redis_server import RedisServer


@pytest.fixture
def store(records_db: Engine, private_redis: RedisServer, tmp_path: Path) -> JobStore:
    return JobStore(LocalStore(tmp_path / "bucket"), redis.Redis.from_url(private_redis.url()), records_db)


def _dispatched(jobs_: JobStore, **fields: object) -> JobRecord:
    """A job as the dispatcher leaves it (stamped, its chain sent), with `fields` on its row."""
    record = JobRecord(id=new_id("j_"), tenant="t", scene_id="s_x", tasks=["a"],
                       callback_url="http://127.0.0.1:9/cb")  # fmt: skip
    jobs_.create_many([record])
    with jobs_.database.begin() as conn:
        conn.execute(update(jobs).where(jobs.c.id == record.id).values(dispatched_at=func.now(), **fields))
    loaded = jobs_.load("t", record.id)
    assert loaded is not None
    return loaded


def _row(db: Engine, job_id: str) -> dict:
    with db.connect() as conn:
        return dict(conn.execute(select(jobs).where(jobs.c.id == job_id)).mappings().one())


def _recovery(store: JobStore, **settings: object) -> Recovery:
    return Recovery(store, ServiceSettings(stage_lock_ttl_s=4, **settings))  # type: ignore[arg-type]


def test_a_job_whose_worker_beats_its_row_is_left_alone(store: JobStore) -> None:
    record = _dispatched(store, state="running", stage="perceive", stage_runs=1)
    assert job_heartbeats.claim(store.database, "t", record.id, "host:1:2:ab", lease_s=4).taken
    assert job_heartbeats.beat(store.database, "t", record.id, "host:1:2:ab").held
    assert _recovery(store).scan(grace_s=0) == []
    assert _row(store.database, record.id)["dispatched_at"] is not None
    assert not job_heartbeats.beat(store.database, "t", record.id, "host:9:9:cd").held  # not its claim


def test_a_claim_keeps_other_deliveries_out_until_it_lapses_or_its_holder_is_dead(store: JobStore) -> None:
    record = _dispatched(store, state="running", stage="fuse", stage_runs=2)
    db = store.database
    assert job_heartbeats.claim(db, "t", record.id, "host:1:2:ab", lease_s=2).taken
    refused = job_heartbeats.claim(db, "t", record.id, "host:3:4:cd", lease_s=2)
    assert not refused.taken and refused.holder == "host:1:2:ab" and 0 < refused.remaining_s <= 2
    taken_over = job_heartbeats.claim(db, "t", record.id, "host:3:4:cd", lease_s=2, dead_owner="host:1:2:ab")
    assert taken_over.taken  # the holder is known dead: no waiting
    assert not job_heartbeats.beat(db, "t", record.id, "host:1:2:ab").held  # the old holder is fenced out
    time.sleep(2.2)
    assert job_heartbeats.claim(db, "t", record.id, "host:5:6:ef", lease_s=2).taken  # lapsed
    job_heartbeats.stage_ended(db, "t", record.id, "host:5:6:ef")
    assert _row(db, record.id)["worker"] is None


def test_a_beat_reads_the_cancel_back_and_an_ended_job_cannot_be_claimed(store: JobStore) -> None:
    record = _dispatched(store, state="running", stage="fuse", stage_runs=2)
    db = store.database
    assert job_heartbeats.claim(db, "t", record.id, "host:1:2:ab", lease_s=4).taken
    assert not job_heartbeats.beat(db, "t", record.id, "host:1:2:ab").cancel_requested
    store.request_cancel("t", record.id)
    assert job_heartbeats.beat(db, "t", record.id, "host:1:2:ab").cancel_requested
    store.save(record.model_copy(update={"state": JobState.failed, "error": "x"}))
    assert job_heartbeats.claim(db, "t", record.id, "host:3:4:cd", lease_s=4).ended


def test_an_unclaimed_job_whose_message_waits_is_left_alone_until_it_waited_too_long(store: JobStore) -> None:
    record = _dispatched(store, state="queued")
    store.touch_live(record)  # the dispatcher's mark: its message was sent ('waiting')
    assert _recovery(store).scan(grace_s=0) == []
    assert _recovery(store, message_wait_s=0.001).scan(grace_s=0) == [record.id]


def test_a_dispatched_job_with_no_live_state_is_a_suspect_at_once(store: JobStore) -> None:
    """Redis lost the message and the live hash with it: no waiting for `message_wait_s`."""
    record = _dispatched(store, state="queued")
    assert _recovery(store).scan(grace_s=0) == [record.id]


def test_a_job_with_every_stage_done_and_no_end_is_finished_once(store: JobStore) -> None:
    """The stuck job: its final write was lost; before, it was requeued for ever with no stage to send."""
    record = _dispatched(store, state="queued", stages_done=list(STAGES), stage_runs=3)
    recovery = _recovery(store)
    assert recovery.scan(grace_s=0) == [record.id]
    assert recovery.scan(grace_s=0) == []  # nothing left to do
    row = _row(store.database, record.id)
    assert row["state"] == "succeeded" and row["finished_at"] is not None
    with store.database.connect() as conn:
        ends = conn.execute(
            select(func.count()).where(usage_ledger.c.job_id == record.id, usage_ledger.c.kind == "end")
        ).scalar_one()
        events = conn.execute(
            select(func.count()).where(callback_outbox.c.url == "http://127.0.0.1:9/cb")
        ).scalar_one()
    assert (ends, events) == (1, 1)


def test_a_job_that_lost_its_worker_is_requeued_and_counted_then_failed_past_the_limit(
    store: JobStore,
) -> None:
    record = _dispatched(store, state="running", stage="fuse", stages_done=["perceive"], stage_runs=2)
    # its worker beat the row, then died: the beat is older than the lease (4 s) by now
    with store.database.begin() as conn:
        conn.execute(update(jobs).where(jobs.c.id == record.id).values(
            worker="host:1:2:ab", heartbeat_at=func.now() - func.make_interval(0, 0, 0, 0, 0, 0, 60)))  # fmt: skip
    recovery = _recovery(store, max_recoveries=2)
    assert recovery.scan(grace_s=0) == [record.id]
    row = _row(store.database, record.id)
    assert (row["state"], row["dispatched_at"], row["recoveries"]) == ("queued", None, 1)
    with store.database.begin() as conn:  # dispatched again, lost again, and once more
        conn.execute(
            update(jobs).where(jobs.c.id == record.id).values(dispatched_at=func.now(), recoveries=2)
        )
    assert recovery.scan(grace_s=0) == [record.id]
    row = _row(store.database, record.id)
    assert row["state"] == JobState.failed.value
    assert "lost its worker 3 times" in row["error"] and "BFIELDS_MAX_RECOVERIES=2" in row["error"]


def test_a_suspect_waits_its_grace_over_two_scans(store: JobStore) -> None:
    record = _dispatched(store, state="queued")
    recovery = _recovery(store)
    assert recovery.scan(grace_s=60) == []  # first seen now
    assert recovery.scan(grace_s=60) == []  # still within its grace
    assert _row(store.database, record.id)["dispatched_at"] is not None
    assert recovery.scan(grace_s=0) == [record.id]


def test_recovery_reads_none_of_the_brokers_keys() -> None:
    """Recovery decides from the row (and the service's own live progress), never from the broker's
    lists: its module imports nothing of the broker adapter and names no queue."""
    import ast

    import bayesian_fields_service.control.recovery as recovery

    tree = ast.parse(Path(recovery.__file__).read_text())
    imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not any(m and (m.endswith("live.broker") or m.startswith("kombu")) for m in imported), imported
    names = {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
    assert not names & {"gpu_queue", "cpu_queue", "lrange", "llen"}, names
