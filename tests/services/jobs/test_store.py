"""`JobStore` over the in-memory fakes of its ports (`fakes.py`): the rules that need the unit of
work, without a server. The same store runs on PostgreSQL and Redis in the integration tests
(`tests/services/webhooks`, `tests/services/stack`)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_service.jobs.batches import BatchRecord
from bayesian_fields_service.jobs.model import JobRecord, JobState, utcnow
from bayesian_fields_service.jobs.queue import AdmissionRefused
from bayesian_fields_service.jobs.store import JobStore, NewJobs
from bayesian_fields_service.jobs.usage import JobUsage
from bayesian_fields_service.records.ids import BATCH_ID, JOB_ID, new_id
from bayesian_fields_service.scenes.refusals import SceneGone, SceneNotReady
from tests.services.jobs.fakes import FakeJobRecords, FakeLiveJobs

SCENE = "s_" + "1" * 22
HOOK = "https://hooks.test/done"


@pytest.fixture
def fakes(tmp_path: Path) -> tuple[JobStore, FakeJobRecords, FakeLiveJobs]:
    records, live = FakeJobRecords(), FakeLiveJobs()
    records.tables.scenes[("t", SCENE)] = "ready"
    return JobStore.over(LocalStore(tmp_path), records, live), records, live


def job(**kw: object) -> JobRecord:
    fields: dict[str, object] = {
        "id": new_id(JOB_ID),
        "tenant": "t",
        "scene_id": SCENE,
        "tasks": ["mug"],
        **kw,
    }
    return JobRecord(**fields)  # type: ignore[arg-type]


def test_a_success_after_an_accepted_cancel_is_stored_cancelled(fakes) -> None:  # noqa: ANN001
    jobs, records, live = fakes
    running = jobs.save(job(state=JobState.running, callback_url=HOOK))
    assert jobs.request_cancel("t", running.id).cancel_requested  # type: ignore[union-attr]
    assert live.is_cancel_flagged("t", running.id)  # the worker is told between frames
    ended = jobs.save(running.model_copy(update={"state": JobState.succeeded, "finished_at": utcnow()}))
    assert ended.state == JobState.cancelled
    assert records.tables.jobs[running.id]["state"] == "cancelled"
    assert [e["state"] for _, _, e in records.tables.outbox.values()] == ["cancelled"]


def test_a_live_cancel_flag_alone_wins_over_a_success(fakes) -> None:  # noqa: ANN001
    jobs, _, live = fakes
    running = jobs.save(job(state=JobState.running))
    live.flag_cancelled([("t", running.id)])
    assert jobs.save(running.model_copy(update={"state": JobState.succeeded})).state == JobState.cancelled


def test_a_jobs_end_writes_its_outbox_and_usage_rows_once(fakes) -> None:  # noqa: ANN001
    jobs, records, _ = fakes
    running = jobs.save(job(state=JobState.running, callback_url=HOOK))
    assert records.tables.outbox == {} and records.tables.usage == {}
    done = running.model_copy(update={"state": JobState.succeeded, "finished_at": utcnow(),
                                      "usage": JobUsage(bytes_stored=42)})  # fmt: skip
    jobs.save(done, answers=[{"task": "mug"}])
    ((tenant, url, event),) = records.tables.outbox.values()
    assert (tenant, url, event["type"], event["job_id"]) == ("t", HOOK, "job.finished", running.id)
    ((entry, _, job_id, outcome, size, _),) = records.tables.usage.values()
    assert (entry, job_id, outcome, size) == (f"{running.id}.end", running.id, "succeeded", 42)
    assert records.tables.answers[running.id] == [{"task": "mug"}]
    again = jobs.save(done.model_copy(update={"finished_at": utcnow()}))  # a redelivered end, stamped anew
    assert again.state == JobState.succeeded
    assert jobs.save(running).state == JobState.succeeded  # a late stage write: sticky
    assert (
        len(records.tables.outbox) == 1 and len(records.tables.usage) == 1
    )  # a duplicate end writes nothing


def test_cancelling_a_waiting_job_ends_it_with_its_rows(fakes) -> None:  # noqa: ANN001
    jobs, records, _ = fakes
    waiting = job(callback_url=HOOK)
    jobs.create(waiting)
    cancelled = jobs.request_cancel("t", waiting.id)
    assert cancelled is not None and cancelled.state == JobState.cancelled
    assert [u[3] for u in records.tables.usage.values()] == ["cancelled"]
    assert len(records.tables.outbox) == 1
    assert jobs.request_cancel("t", waiting.id).cancel_requested  # type: ignore[union-attr]
    assert len(records.tables.outbox) == 1 and len(records.tables.usage) == 1  # not accepted twice


def test_admission_refuses_past_the_limit_and_leaves_nothing(fakes) -> None:  # noqa: ANN001
    jobs, records, _ = fakes
    jobs.create_many([job(), job()], NewJobs(admit_limit=3, scene_ids=[SCENE]))
    with pytest.raises(AdmissionRefused) as refused:
        jobs.create_many([job(idempotency_key="k"), job()], NewJobs(admit_limit=3, scene_ids=[SCENE]))
    assert (refused.value.active, refused.value.limit, refused.value.asked) == (2, 3, 2)
    assert (
        len(records.tables.jobs) == 2 and records.tables.keys == {}
    )  # the refused unit of work left nothing
    jobs.create_many([job()], NewJobs(admit_limit=3))  # exactly up to the limit
    ended = next(iter(records.tables.jobs))
    jobs.request_cancel("t", ended)  # an ended job stops counting
    jobs.create_many([job()], NewJobs(admit_limit=3))
    assert jobs.count_active("t") == 3


def test_a_scene_not_ready_or_gone_refuses_the_submission(fakes) -> None:  # noqa: ANN001
    jobs, records, _ = fakes
    uploading = "s_" + "2" * 22
    records.tables.scenes[("t", uploading)] = "uploading"
    with pytest.raises(SceneNotReady):
        jobs.create_many([job(scene_id=uploading)], NewJobs(scene_ids=[uploading]))
    with pytest.raises(SceneGone):
        jobs.create_many([job(scene_id="s_" + "3" * 22)], NewJobs(scene_ids=["s_" + "3" * 22]))
    assert records.tables.jobs == {}


def test_an_idempotency_key_keeps_its_first_job_until_a_retry_replaces_it(fakes) -> None:  # noqa: ANN001
    jobs, _, _ = fakes
    first, second = job(idempotency_key="k"), job(idempotency_key="k")
    jobs.create_many([first], NewJobs(digests={first.id: "d1"}))
    jobs.create_many([second], NewJobs(digests={second.id: "d2"}))
    assert jobs.idempotent_job("t", "k") == (first.id, "d1")
    assert jobs.idempotent_jobs("t", ["k", "other"]) == {"k": (first.id, "d1")}
    batch = BatchRecord(id=new_id(BATCH_ID), tenant="t")
    jobs.create_many([], NewJobs(batch=batch, batch_job_ids=[first.id]))
    again = job(idempotency_key="k", batch_id=batch.id, retry_of=first.id)
    jobs.create_many([again], NewJobs(digests={again.id: "d1"}, retry_in=batch.id))
    assert jobs.idempotent_job("t", "k") == (again.id, "d1")
    assert [j.id for _, j in jobs.batch_jobs(batch)] == [again.id]  # the retry took its slot


def test_a_batch_key_row_goes_in_with_the_batch(fakes) -> None:  # noqa: ANN001
    jobs, _, _ = fakes
    batch = BatchRecord(id=new_id(BATCH_ID), tenant="t", idempotency_key="bk")
    items = [job(batch_id=batch.id) for _ in range(3)]
    jobs.create_many(items, NewJobs(batch=batch, batch_digest="body"))
    assert jobs.idempotent_batch("t", "bk") == (batch.id, "body")
    loaded = jobs.load_batch("t", batch.id)
    assert loaded is not None and loaded.total == 3 and loaded.counts["queued"] == 3
    jobs.forget_idempotent_batch("t", "bk", batch.id)
    assert jobs.idempotent_batch("t", "bk") is None


def test_a_batch_cancel_ends_its_waiting_jobs_and_the_batch_once(fakes) -> None:  # noqa: ANN001
    jobs, records, live = fakes
    batch = BatchRecord(id=new_id(BATCH_ID), tenant="t", callback_url=HOOK)
    items = [job(batch_id=batch.id) for _ in range(3)]
    jobs.create_many(items, NewJobs(batch=batch))
    jobs.save(items[0].model_copy(update={"state": JobState.running}))
    changed = jobs.cancel_batch("t", batch.id)
    assert sorted(c.state.value for c in changed) == ["cancelled", "cancelled", "running"]
    assert live.is_cancel_flagged("t", items[0].id)  # the running one is told, not ended
    assert len(records.tables.usage) == 2 and not any(e["type"] == "batch.finished"
                                                      for _, _, e in records.tables.outbox.values())  # fmt: skip
    jobs.save(items[0].model_copy(update={"state": JobState.succeeded}))  # its worker's last save
    finished = [e for _, _, e in records.tables.outbox.values() if e["type"] == "batch.finished"]
    assert len(finished) == 1 and finished[0]["counts"] == {"cancelled": 3}
    jobs.save(items[0].model_copy(update={"state": JobState.failed}))
    assert len([e for _, _, e in records.tables.outbox.values() if e["type"] == "batch.finished"]) == 1


def test_reads_overlay_live_progress_only_while_a_job_runs(fakes) -> None:  # noqa: ANN001
    jobs, _, _ = fakes
    running = jobs.save(job(state=JobState.running, stage="perceive"))
    jobs.set_progress(running, "perceive", 0.5)
    got = jobs.get("t", running.id)
    assert got is not None and got.progress == 30.0 and jobs.live_phase("t", running.id) == "active"
    done = jobs.save(running.model_copy(update={"state": JobState.failed, "error": "x"}))
    assert jobs.get("t", done.id).state == JobState.failed  # type: ignore[union-attr]
    page, cursor = jobs.list("t", state=JobState.failed)
    assert [j.id for j in page] == [done.id] and cursor is None


def test_a_local_bucket_names_the_tenants_file_and_another_bucket_none(tmp_path: Path) -> None:
    """`local_file` (what `GET /v1/jobs/{id}/artifacts/...` serves on a local folder): the file a
    key names in the tenant's part of the bucket, another tenant's key elsewhere; None where the
    bucket is not a local folder (such a bucket presigns, the route answers 404)."""
    bucket = LocalStore(tmp_path / "bucket")
    jobs = JobStore.over(bucket, FakeJobRecords(), FakeLiveJobs())
    key = "jobs/j_1/result/summary.json"
    jobs.tenant("t").put_bytes(key, b"{}")
    found = jobs.local_file("t", key)
    assert found is not None and found.is_file() and found.read_bytes() == b"{}"
    assert found.is_relative_to(bucket.root)
    other = jobs.local_file("u", key)
    assert other is not None and other != found and not other.is_file()
    wrapped = JobStore.over(jobs.tenant("t"), FakeJobRecords(), FakeLiveJobs())  # not a LocalStore
    assert wrapped.local_file("t", key) is None
