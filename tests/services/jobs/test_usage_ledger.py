"""The usage ledger in the records database (issue 28, items 1 and 6), through the jobs domain's
own writes on a real PostgreSQL and Redis: every job end counts once whoever ends it (a worker's
save, a cancel while waiting, a batch cancel), a retried stage write counts once, a Redis loss
changes nothing, tenants and days are apart."""

from __future__ import annotations

from datetime import UTC, date, datetime, timedelta
from pathlib import Path

import pytest
import redis
from sqlalchemy import Engine

from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_service.jobs import usage
from bayesian_fields_service.jobs.batches import BatchRecord
from bayesian_fields_service.jobs.model import JobRecord, JobState
from bayesian_fields_service.jobs.store import JobStore, NewJobs
from bayesian_fields_service.jobs.usage import JobUsage
from bayesian_fields_service.records.ids import new_id
from tests.integration.fixtures.redis_server import RedisServer


@pytest.fixture
def db(records_db: Engine) -> Engine:
    return records_db


def _job(tenant: str, batch_id: str | None = None) -> JobRecord:
    return JobRecord(id=new_id("j_"), tenant=tenant, scene_id="s_x", tasks=["a"], batch_id=batch_id)


def test_every_end_counts_once_whoever_ends_the_job(
    db: Engine, private_redis: RedisServer, tmp_path: Path
) -> None:
    client = redis.Redis.from_url(private_redis.url())
    jobs = JobStore(LocalStore(tmp_path / "bucket"), client, db)
    today = datetime.now(UTC).date()

    ran = _job("t")
    waiting = _job("t")
    batch = BatchRecord(id=new_id("b_"), tenant="t", total=3)
    in_batch = [_job("t", batch.id) for _ in range(3)]
    other = _job("u")
    jobs.create_many([ran, waiting, other])
    jobs.create_many(in_batch, NewJobs(batch=batch))

    # a worker ran two stages of `ran` (the second write of a stage retried: counted once), then it ended
    when = datetime.now(UTC)
    for stage, cpu in (("perceive", 2.5), ("fuse", 1.25), ("fuse", 1.25)):
        usage.record_stage(db, "t", ran.id, stage, 1 if stage == "perceive" else 2, cpu, 0.0, when)
    done = ran.model_copy(update={"state": JobState.succeeded, "usage": JobUsage(bytes_stored=1000)})
    jobs.save(done)
    jobs.save(done)  # a duplicate end (a redelivered message)
    jobs.request_cancel("t", waiting.id)  # cancelled while it waited: no worker ever saw it
    jobs.cancel_batch("t", batch.id)  # three more, in one statement
    jobs.save(other.model_copy(update={"state": JobState.failed, "error": "x"}))

    client.flushall()  # Redis loses everything: the ledger is not there
    report = usage.tenant_usage(db, "t", today - timedelta(days=1), today)
    total = report["total"]
    assert total["jobs"] == 5 and total["jobs_by_state"] == {"succeeded": 1, "cancelled": 4}
    assert total["stage_runs"] == 2 and total["cpu_seconds"] == 3.75 and total["bytes_stored"] == 1000
    assert total["by_stage"] == {"perceive": {"cpu_seconds": 2.5, "gpu_seconds": 0.0},
                                 "fuse": {"cpu_seconds": 1.25, "gpu_seconds": 0.0}}  # fmt: skip
    assert [d["day"] for d in report["days"]] == [today.isoformat()]
    assert usage.tenant_usage(db, "u", today, today)["total"]["jobs_by_state"] == {"failed": 1}
    assert usage.tenant_usage(db, "t", today + timedelta(days=1), today + timedelta(days=2))["days"] == []


def test_days_are_utc_days(db: Engine) -> None:
    """A stage recorded at 23:59 UTC and one at 00:01 UTC the next day fall on two days."""
    late = datetime(2026, 3, 1, 23, 59, tzinfo=UTC)
    usage.record_stage(db, "t", "j_a", "perceive", 1, 1.0, 0.5, late)
    usage.record_stage(db, "t", "j_a", "fuse", 1, 2.0, 0.0, late + timedelta(minutes=2))
    report = usage.tenant_usage(db, "t", date(2026, 3, 1), date(2026, 3, 2))
    assert [(d["day"], d["cpu_seconds"], d["gpu_seconds"]) for d in report["days"]] == [
        ("2026-03-01", 1.0, 0.5),
        ("2026-03-02", 2.0, 0.0),
    ]
    assert usage.tenant_usage(db, "t", date(2026, 3, 2), date(2026, 3, 2))["total"]["cpu_seconds"] == 2.0
