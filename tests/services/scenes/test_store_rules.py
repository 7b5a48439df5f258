"""The rules over scene rows (`scenes.store`) on the in-memory records: a deleting row reads as
absent everywhere and never comes back, only an uploading scene is published, a job needs every
scene ready. The same rules with PostgreSQL's row locks: test_store_postgres.py."""

from __future__ import annotations

import pytest

from bayesian_fields_service.scenes.model import DeletingScene, SceneRecord, SceneState
from bayesian_fields_service.scenes.refusals import SceneGone, SceneNotReady, SceneNotUploading
from bayesian_fields_service.scenes.store import SceneStore, ready_scenes
from tests.services.scenes.conftest import T0
from tests.services.scenes.fakes import InMemorySceneRecords


def _scene(store: SceneStore, n: int, state: SceneState = SceneState.ready) -> SceneRecord:
    record = SceneRecord(id=f"s_{n:022x}", tenant="acme", state=state, created_at=T0, updated_at=T0)
    store.create(record)
    return record


def test_publish_turns_only_an_uploading_scene_ready(records: InMemorySceneRecords) -> None:
    store = SceneStore(records)
    up = _scene(store, 1, SceneState.uploading)
    ready = store.publish_ready("acme", up.id, files=3, size=30, summary={"frames": 2})
    assert (ready.state, ready.files, ready.bytes) == (SceneState.ready, 3, 30)
    with pytest.raises(SceneNotUploading, match="is already ready"):
        store.publish_ready("acme", up.id, files=1, size=1, summary={})
    assert store.get("acme", up.id) == ready  # the refused change left nothing


def test_a_deleting_scene_is_absent_and_cannot_be_published_or_deleted_again(
    records: InMemorySceneRecords,
) -> None:
    store = SceneStore(records)
    up = _scene(store, 1, SceneState.uploading)
    assert store.mark_deleting("acme", up.id) == up  # the record as it was (its uploads to abort)
    assert store.get("acme", up.id) is None and store.list("acme", 10) == ([], None)
    with pytest.raises(SceneGone):
        store.publish_ready("acme", up.id, files=1, size=1, summary={})
    with pytest.raises(SceneGone):
        store.mark_deleting("acme", up.id)
    assert store.deleting_scenes() == [DeletingScene("acme", up.id, [])]
    store.purge("acme", up.id)
    assert store.deleting_scenes() == [] and store.listed_uploads("acme", [up.id]) == {}


def test_purge_leaves_a_scene_that_is_not_being_deleted(records: InMemorySceneRecords) -> None:
    store = SceneStore(records)
    kept = _scene(store, 1)
    store.purge("acme", kept.id)
    assert store.get("acme", kept.id) == kept


def test_a_job_needs_every_scene_ready_and_the_first_missing_one_is_named(
    records: InMemorySceneRecords,
) -> None:
    store = SceneStore(records)
    ready, up, gone = _scene(store, 1), _scene(store, 2, SceneState.uploading), _scene(store, 3)
    store.mark_deleting("acme", gone.id)
    with records.transaction() as rows:
        assert ready_scenes(rows, "acme", [ready.id, ready.id]) == {ready.id: ready}
        with pytest.raises(SceneGone, match=gone.id):
            ready_scenes(rows, "acme", [ready.id, gone.id, up.id])
        with pytest.raises(SceneNotReady, match=f"{up.id}' is not ready"):
            ready_scenes(rows, "acme", [up.id, "s_missing"])
        with pytest.raises(SceneGone, match="s_missing"):
            ready_scenes(rows, "acme", ["s_missing", up.id])
