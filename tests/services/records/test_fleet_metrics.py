"""What `/metrics` reads of the rows (`records.fleet_metrics`), on a real PostgreSQL: active jobs
by state (every active state, 0 where none), the callback outbox's open events and the age of the
oldest, whether the leader's lease is held (and not once it expired), and the stalled jobs (a
worker's claim whose heartbeat is older than the lease; a fresh claim or an unclaimed job is not)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import redis
from sqlalchemy import Engine, func, update

from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_service.jobs.model import JobRecord
from bayesian_fields_service.jobs.store import JobStore
from bayesian_fields_service.records import fleet_metrics, job_heartbeats, leases, outbox
from bayesian_fields_service.records.ids import new_id
from bayesian_fields_service.records.tables import callback_outbox, jobs
from tests.integration.fixtures.redis_server import RedisServer

LEASE_S = 2.0


@pytest.fixture
def store(records_db: Engine, private_redis: RedisServer, tmp_path: Path) -> JobStore:
    return JobStore(LocalStore(tmp_path / "bucket"), redis.Redis.from_url(private_redis.url()), records_db)


def _job(store: JobStore, **fields: object) -> str:
    record = JobRecord(id=new_id("j_"), tenant="t", scene_id="s_x", tasks=["a"])
    store.create_many([record])
    if fields:
        with store.database.begin() as conn:
            conn.execute(update(jobs).where(jobs.c.id == record.id).values(**fields))
    return record.id


def _read(store: JobStore) -> fleet_metrics.FleetRows:
    return store.fleet_rows(LEASE_S)


def test_an_empty_fleet_reads_zeros_for_every_active_state(store: JobStore) -> None:
    rows = _read(store)
    assert rows.jobs_by_state == {"queued": 0, "running": 0}
    assert (rows.outbox_open, rows.outbox_oldest_age_s, rows.leader_held, rows.stalled_jobs) == (
        0,
        0.0,
        False,
        0,
    )


def test_jobs_by_state_and_stalled_claims_are_read_from_the_rows(store: JobStore) -> None:
    db = store.database
    _job(store)  # waiting in its queue
    fresh = _job(store, state="running", stage="perceive", dispatched_at=func.now())
    silent = _job(store, state="running", stage="fuse", dispatched_at=func.now())
    _job(store, state="running", dispatched_at=func.now())  # dispatched, its message not taken yet
    _job(store, state="succeeded")  # finished: not an active state
    assert job_heartbeats.claim(db, "t", fresh, "host:1:1:a", lease_s=LEASE_S).taken
    assert job_heartbeats.claim(db, "t", silent, "host:2:2:b", lease_s=LEASE_S).taken
    assert _read(store).stalled_jobs == 0  # both heartbeats are fresh
    time.sleep(LEASE_S + 0.3)
    assert job_heartbeats.beat(db, "t", fresh, "host:1:1:a").held  # one worker beats, one went silent
    rows = _read(store)
    assert rows.jobs_by_state == {"queued": 1, "running": 3}
    assert rows.stalled_jobs == 1
    job_heartbeats.stage_ended(db, "t", silent, "host:2:2:b")  # a stage that ended gives its claim up
    assert _read(store).stalled_jobs == 0


def test_the_outbox_counts_open_events_and_ages_the_oldest(store: JobStore) -> None:
    db = store.database
    with db.begin() as conn:
        for n in range(3):
            outbox.enqueue(conn, "t", "http://127.0.0.1:9/cb", f"ev-{n}", {"n": n})
        conn.execute(update(callback_outbox).where(callback_outbox.c.event_id == "ev-0")
                     .values(created_at=func.now() - func.make_interval(0, 0, 0, 0, 0, 2)))  # fmt: skip
    rows = _read(store)
    assert rows.outbox_open == 3 and 119 < rows.outbox_oldest_age_s < 180, rows
    with db.begin() as conn:
        ids = dict(conn.execute(callback_outbox.select().with_only_columns(
            callback_outbox.c.event_id, callback_outbox.c.id)).all())  # fmt: skip
        assert outbox.mark_delivered(conn, ids["ev-0"], 1)
        assert outbox.mark_dropped(conn, ids["ev-1"], 5, "gone")
    rows = _read(store)
    assert rows.outbox_open == 1 and rows.outbox_oldest_age_s < 60, rows  # delivered / dropped: closed


def test_the_leader_gauge_follows_the_lease_row(store: JobStore) -> None:
    db = store.database
    token = leases.take_or_renew(db, leases.CONTROL_LEADER, "control-a", None, ttl_s=60)
    assert token is not None and _read(store).leader_held
    assert leases.release(db, leases.Fence(leases.CONTROL_LEADER, token), "control-a")
    assert not _read(store).leader_held  # released (expired now): nobody leads
