"""Scene rows (`scenes.store` over `scenes.postgres`) on a real PostgreSQL: keyset pages newest first without deleting
scenes, the life uploading -> ready -> deleting -> purged with its refusals, and the row locks
that order a delete against a job submission and a completion (two threads, two connections)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta

import pytest
from sqlalchemy import Engine, insert, update

from bayesian_fields_service.records.ids import new_id
from bayesian_fields_service.records.tables import jobs
from bayesian_fields_service.scenes.model import SceneRecord, SceneState
from bayesian_fields_service.scenes.postgres import lock_ready, scene_store
from bayesian_fields_service.scenes.refusals import SceneBusy, SceneGone, SceneNotReady, SceneNotUploading
from bayesian_fields_service.scenes.store import SceneStore

T0 = datetime(2026, 1, 2, 3, 4, 5, 678901, tzinfo=UTC)


def _scene(
    scenes: SceneStore, tenant: str, *, state: SceneState = SceneState.ready, n: int = 0
) -> SceneRecord:
    when = T0 + timedelta(seconds=n)
    record = SceneRecord(
        id=new_id("s_"), tenant=tenant, name=f"scene {n}", state=state, files=3, bytes=1234,
        summary={"frames": 4, "camera_format": "transforms"}, created_at=when, updated_at=when,
        pending_uploads=[{"key": "k", "upload_id": f"up-{n}"}] if state == SceneState.uploading else [],
    )  # fmt: skip
    scenes.create(record)
    time.sleep(0.002)  # ids are ms-ordered: one scene per millisecond keeps "newest first" exact
    return record


def _job(db: Engine, tenant: str, scene_id: str, state: str = "queued") -> str:
    job_id = new_id("j_")
    with db.begin() as conn:
        conn.execute(
            insert(jobs).values(id=job_id, tenant=tenant, scene_id=scene_id, state=state, priority="bulk",
                                tasks=["x"], model_profile="default")
        )  # fmt: skip
    return job_id


def _in_thread(fn: Callable[[], object]) -> tuple[threading.Thread, list[object]]:
    """Run `fn` in a thread; its result or exception lands in the list."""
    out: list[object] = []

    def run() -> None:
        try:
            out.append(fn())
        except Exception as exc:  # the test asserts on it
            out.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread, out


def test_a_page_is_newest_first_without_deleting_or_other_tenants_scenes(records_db: Engine) -> None:
    scenes = scene_store(records_db)
    made = [
        _scene(scenes, "acme", n=n, state=SceneState.uploading if n == 2 else SceneState.ready)
        for n in range(7)
    ]
    _scene(scenes, "other", n=9)
    scenes.mark_deleting("acme", made[4].id)
    expected = [r.id for r in reversed(made) if r.id != made[4].id]
    seen: list[str] = []
    cursor: str | None = None
    for _ in range(4):
        page, cursor = scenes.list("acme", 2, cursor)
        seen += [r.id for r in page]
        assert len(page) == 2 or cursor is None
        if cursor is None:
            break
    assert seen == expected
    assert scenes.list("acme", 6, None) == ([r for r in reversed(made) if r.id != made[4].id], None)
    assert scenes.list("acme", 50, made[1].id) == ([made[0]], None)
    assert scenes.list("nobody", 5, None) == ([], None)


def test_a_record_reads_back_as_it_was_created(records_db: Engine) -> None:
    scenes = scene_store(records_db)
    record = _scene(scenes, "acme", state=SceneState.uploading)
    assert scenes.get("acme", record.id) == record
    assert scenes.get("other", record.id) is None  # another tenant's id is no scene of this one


def test_publish_turns_an_uploading_scene_ready_once(records_db: Engine) -> None:
    scenes = scene_store(records_db)
    record = _scene(scenes, "acme", state=SceneState.uploading)
    ready = scenes.publish_ready("acme", record.id, files=6, size=999, summary={"frames": 4})
    assert ready.state == SceneState.ready and ready.pending_uploads == []
    assert (ready.files, ready.bytes, ready.summary) == (6, 999, {"frames": 4})
    assert ready.updated_at > record.updated_at and ready.created_at == record.created_at
    assert scenes.get("acme", record.id) == ready
    with pytest.raises(SceneNotUploading, match="already ready"):
        scenes.publish_ready("acme", record.id, files=1, size=1, summary={})
    assert scenes.get("acme", record.id) == ready


def test_a_deleted_scene_is_gone_for_good(records_db: Engine) -> None:
    scenes = scene_store(records_db)
    record = _scene(scenes, "acme", state=SceneState.uploading)
    assert scenes.mark_deleting("acme", record.id) == record  # as it was: its uploads to abort
    assert scenes.get("acme", record.id) is None
    with pytest.raises(SceneGone):
        scenes.publish_ready("acme", record.id, files=1, size=1, summary={})
    with pytest.raises(SceneGone):
        scenes.mark_deleting("acme", record.id)
    with records_db.begin() as conn, pytest.raises(SceneGone):
        lock_ready(conn, "acme", [record.id])
    assert [(d.tenant, d.id, d.pending_uploads) for d in scenes.deleting_scenes()] == [
        ("acme", record.id, record.pending_uploads)
    ]
    scenes.purge("acme", record.id)
    assert scenes.deleting_scenes() == [] and scenes.listed_uploads("acme", [record.id]) == {}
    with pytest.raises(SceneGone):
        scenes.publish_ready("acme", record.id, files=1, size=1, summary={})


def test_purge_leaves_a_scene_that_is_not_being_deleted(records_db: Engine) -> None:
    scenes = scene_store(records_db)
    record = _scene(scenes, "acme")
    scenes.purge("acme", record.id)
    assert scenes.get("acme", record.id) == record


def test_delete_is_refused_while_a_job_on_the_scene_is_queued_or_running(records_db: Engine) -> None:
    scenes = scene_store(records_db)
    record = _scene(scenes, "acme")
    _job(records_db, "acme", record.id, "succeeded")  # a finished job never blocks
    job_id = _job(records_db, "acme", record.id, "queued")
    with pytest.raises(SceneBusy) as refused:
        scenes.mark_deleting("acme", record.id)
    assert (refused.value.job_id, refused.value.job_state) == (job_id, "queued")
    assert job_id in str(refused.value) and "queued" in str(refused.value)
    with records_db.begin() as conn:
        conn.execute(update(jobs).where(jobs.c.id == job_id).values(state="running"))
    with pytest.raises(SceneBusy, match=f"running job {job_id}"):
        scenes.mark_deleting("acme", record.id)
    assert scenes.get("acme", record.id) == record
    with records_db.begin() as conn:
        conn.execute(update(jobs).where(jobs.c.id == job_id).values(state="cancelled"))
    scenes.mark_deleting("acme", record.id)
    assert scenes.get("acme", record.id) is None


def test_lock_ready_names_the_first_scene_that_is_missing_or_not_ready(records_db: Engine) -> None:
    scenes = scene_store(records_db)
    ready, other = _scene(scenes, "acme"), _scene(scenes, "acme", n=1)
    uploading = _scene(scenes, "acme", state=SceneState.uploading, n=2)
    missing = new_id("s_")
    with records_db.begin() as conn:
        assert lock_ready(conn, "acme", [other.id, ready.id, other.id]) == {other.id: other, ready.id: ready}
        assert lock_ready(conn, "acme", []) == {}
    with records_db.begin() as conn, pytest.raises(SceneGone) as gone:
        lock_ready(conn, "acme", [ready.id, missing, uploading.id])
    assert gone.value.scene_id == missing
    with records_db.begin() as conn, pytest.raises(SceneNotReady, match="not ready"):
        lock_ready(conn, "acme", [ready.id, uploading.id])
    with records_db.begin() as conn, pytest.raises(SceneGone):
        lock_ready(conn, "other", [ready.id])


def _delete_while_held(
    scenes: SceneStore, record: SceneRecord, holder: Callable[[Callable[[], None]], object]
) -> tuple[object, object]:
    """Run `holder` in a thread; it calls the function it is given while its transaction holds
    the scene's row. Meanwhile a delete starts on another connection: it must wait until the
    holder is released. Returns (the holder's result, the delete's result or exception)."""
    locked, release = threading.Event(), threading.Event()

    def hold() -> None:
        locked.set()
        assert release.wait(30)

    holding, held = _in_thread(lambda: holder(hold))
    assert locked.wait(30)
    deleter, deleted = _in_thread(lambda: scenes.mark_deleting(record.tenant, record.id))
    time.sleep(0.5)
    assert deleted == [], "the delete did not wait for the transaction holding the scene's row"
    release.set()
    holding.join(30)
    deleter.join(30)
    return held[0], deleted[0]


def test_a_submission_holding_the_scene_makes_the_delete_wait_and_then_see_its_job(
    records_db: Engine,
) -> None:
    """The submission's transaction share-locks the row, inserts a job and holds on; the delete
    (another connection) waits for its commit, then finds the active job and is refused."""
    scenes = scene_store(records_db)
    record = _scene(scenes, "acme")
    job_id = new_id("j_")

    def submit(hold: Callable[[], None]) -> str:
        with records_db.begin() as conn:
            lock_ready(conn, "acme", [record.id])
            conn.execute(
                insert(jobs).values(id=job_id, tenant="acme", scene_id=record.id, priority="bulk", tasks=["x"],
                                    model_profile="default")
            )  # fmt: skip
            hold()
        return job_id

    submitted, deleted = _delete_while_held(scenes, record, submit)
    assert submitted == job_id
    assert isinstance(deleted, SceneBusy) and deleted.job_id == job_id
    assert scenes.get("acme", record.id) == record


def test_a_submission_after_the_delete_finds_the_scene_gone(records_db: Engine) -> None:
    """The delete committed first: the submission's share lock finds the row deleting."""
    scenes = scene_store(records_db)
    record = _scene(scenes, "acme")
    scenes.mark_deleting("acme", record.id)
    with records_db.begin() as conn, pytest.raises(SceneGone):
        lock_ready(conn, "acme", [record.id])


def test_a_publishing_completion_makes_the_delete_wait_then_the_delete_wins(records_db: Engine) -> None:
    """The completion holds the row while it publishes (`while_locked`); the delete waits for the
    ready record and then marks the complete scene deleting."""
    scenes = scene_store(records_db)
    record = _scene(scenes, "acme", state=SceneState.uploading)
    published, deleted = _delete_while_held(
        scenes,
        record,
        lambda hold: scenes.publish_ready("acme", record.id, files=1, size=2, summary={}, while_locked=hold),
    )
    assert isinstance(published, SceneRecord) and published.state == SceneState.ready
    assert (
        isinstance(deleted, SceneRecord) and deleted.state == SceneState.ready
    )  # the ready scene is deleted
    assert scenes.get("acme", record.id) is None
