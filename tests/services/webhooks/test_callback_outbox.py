"""The transactional outbox (issue 28, item 4) through the jobs domain's own writes, on a real
PostgreSQL and a real Redis: a batch whose first job ended before Redis lost everything and whose
second ended after still queues its batch event, once; a job's event is a row of the transaction
that ended it; a repeated terminal write queues nothing more."""

from __future__ import annotations

from pathlib import Path

import pytest
import redis
from sqlalchemy import Engine, select

from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_service.jobs.batches import BatchRecord
from bayesian_fields_service.jobs.model import JobRecord, JobState
from bayesian_fields_service.jobs.store import JobStore, NewJobs
from bayesian_fields_service.records.ids import new_id
from bayesian_fields_service.records.tables import callback_outbox
from tests.integration.fixtures.redis_server import RedisServer


@pytest.fixture
def db(records_db: Engine) -> Engine:
    return records_db


def _events(db: Engine) -> list[dict]:
    with db.connect() as conn:
        return [dict(r) for r in conn.execute(select(callback_outbox).order_by(callback_outbox.c.id)).mappings()]


def test_a_batch_event_survives_a_redis_loss_between_its_jobs(
    db: Engine, private_redis: RedisServer, tmp_path: Path
) -> None:
    client = redis.Redis.from_url(private_redis.url())
    jobs = JobStore(LocalStore(tmp_path / "bucket"), client, db)
    batch = BatchRecord(id=new_id("b_"), tenant="t", total=2, callback_url="https://hooks.example.com/b")
    records = [
        JobRecord(id=new_id("j_"), tenant="t", scene_id="s_x", tasks=[f"task {i}"], batch_id=batch.id,
                  callback_url="https://hooks.example.com/j" if i == 0 else None)
        for i in range(2)
    ]  # fmt: skip
    jobs.create_many(records, NewJobs(batch=batch))

    first = jobs.save(records[0].model_copy(update={"state": JobState.succeeded}))
    events = _events(db)
    assert [e["event"]["type"] for e in events] == ["job.finished"]  # the job's own; the batch waits
    assert events[0]["event"]["job_id"] == first.id and events[0]["tenant"] == "t"

    client.flushall()  # Redis loses everything between the two ends
    jobs.save(records[1].model_copy(update={"state": JobState.failed, "error": "boom"}))
    jobs.save(records[1].model_copy(update={"state": JobState.failed, "error": "boom"}))  # a duplicate end
    events = _events(db)
    assert [e["event"]["type"] for e in events] == ["job.finished", "batch.finished"]
    done = events[1]["event"]
    assert done["batch_id"] == batch.id and done["jobs"] == 2 and done["counts"] == {"succeeded": 1, "failed": 1}
    assert events[1]["url"] == "https://hooks.example.com/b" and events[1]["delivered_at"] is None
