"""The upgrade path from scene records kept in the bucket (`scenes.legacy_import`,
`bfields-service import-scenes`) on a real S3 server and a real PostgreSQL: every record becomes
a row under the tenant its key names, a tombstoned scene a deleting row that the sweeper then
finishes, nothing in the bucket is changed, and a second run inserts nothing."""

from __future__ import annotations

import dataclasses
import json
import os
import secrets
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import Engine

from bayesian_fields_service.records.ids import new_id
from bayesian_fields_service.scenes.bucket_sweep import sweep_bucket
from bayesian_fields_service.scenes.legacy_import import import_scenes
from bayesian_fields_service.scenes.model import SceneState
from bayesian_fields_service.scenes.postgres import scene_store
from bayesian_fields_service.storage.s3_store import S3Store
from tests.integration.fixtures.s3_server import S3Server


@pytest.fixture
def own_bucket(s3_server: S3Server) -> Iterator[S3Server]:
    """A bucket of this test's own on the session's S3 server: the import walks a whole bucket."""
    view = dataclasses.replace(s3_server, bucket=f"import-{secrets.token_hex(4)}")
    view.store().ensure_bucket()
    yield view
    view.store().delete_prefix("tenants/")


def _record(scene_id: str, tenant: str, **fields: object) -> bytes:
    data = {"id": scene_id, "tenant": tenant, "name": "old", "state": "ready", "files": 2, "bytes": 30,
            "summary": {"frames": 4}, "pending_uploads": [], "created_at": "2025-05-01T10:00:00Z",
            "updated_at": "2025-05-01T10:05:00Z", **fields}  # fmt: skip
    return json.dumps(data).encode()


def _old_release_bucket(store: S3Store) -> dict[str, str]:
    """A bucket as an earlier release left it: records, listing markers, a tombstone, an orphan."""
    ids = {name: new_id("s_") for name in ("ready", "uploading", "deleted", "orphan", "broken", "moved")}
    acme = "tenants/acme/"
    for name in ("ready", "uploading", "deleted", "broken"):
        store.put_bytes(f"{acme}index/scenes/{ids[name]}", b"")
        store.put_bytes(f"{acme}scenes/{ids[name]}/input/splat.ply", b"ply")
    store.put_bytes(f"{acme}scenes/{ids['ready']}/scene.json", _record(ids["ready"], "acme"))
    pending = [{"field": "images", "name": "a.zip", "key": "k", "upload_id": "u1", "size": 5}]
    store.put_bytes(
        f"{acme}scenes/{ids['uploading']}/scene.json",
        _record(ids["uploading"], "acme", state="uploading", files=0, bytes=0, pending_uploads=pending),
    )
    store.put_bytes(f"{acme}scenes/{ids['deleted']}/scene.json", _record(ids["deleted"], "acme"))
    store.put_bytes(f"{acme}tombstones/scenes/{ids['deleted']}", b"")
    store.put_bytes(f"{acme}scenes/{ids['orphan']}/input/splat.ply", b"ply")  # no record: not a scene
    store.put_bytes(f"{acme}scenes/{ids['broken']}/scene.json", b"{not json")
    # a record whose body names another tenant: the key's tenant is the owner
    store.put_bytes(
        f"tenants/beta/scenes/{ids['moved']}/scene.json", _record(ids["moved"], "acme", name="n\ud800")
    )
    return ids


def test_import_makes_a_row_per_record_and_a_second_run_adds_none(
    own_bucket: S3Server, records_db: Engine
) -> None:
    store, scenes = own_bucket.store(), scene_store(records_db)
    ids = _old_release_bucket(store)
    # upgraded but not yet imported: the sweeper keeps every folder holding an old record
    early = sweep_bucket(store, scenes, max_age_s=0)
    assert early.deleted_prefixes == [f"tenants/acme/scenes/{ids['orphan']}/"]
    before = store.list("tenants/")
    report = import_scenes(store, scenes)
    assert (report.imported, report.deleting, report.present) == (4, 1, 0)
    assert report.unreadable == [f"tenants/acme/scenes/{ids['broken']}/scene.json"]
    assert "4 imported (1 of them deleted" in report.line()

    ready = scenes.get("acme", ids["ready"])
    assert ready is not None and ready.state == SceneState.ready
    assert (ready.name, ready.files, ready.bytes, ready.summary) == ("old", 2, 30, {"frames": 4})
    assert ready.created_at.isoformat() == "2025-05-01T10:00:00+00:00"
    uploading = scenes.get("acme", ids["uploading"])
    assert uploading is not None and uploading.state == SceneState.uploading
    assert uploading.pending_uploads[0]["upload_id"] == "u1"
    assert scenes.get("acme", ids["deleted"]) is None
    assert [d.id for d in scenes.deleting_scenes()] == [ids["deleted"]]
    assert scenes.get("acme", ids["orphan"]) is None and scenes.get("acme", ids["broken"]) is None
    moved = scenes.get("beta", ids["moved"])
    assert moved is not None and moved.name == "n\ufffd" and scenes.get("acme", ids["moved"]) is None
    assert store.list("tenants/") == before  # the bucket is read, never changed

    again = import_scenes(store, scenes)
    assert (again.imported, again.deleting, again.present) == (0, 0, 4)

    # the deleting row is the sweeper's to finish at once; the imported scenes it leaves alone
    report_sweep = sweep_bucket(store, scenes, max_age_s=3600)
    assert f"tenants/acme/scenes/{ids['deleted']}/" in report_sweep.deleted_prefixes
    assert store.list(f"tenants/acme/scenes/{ids['deleted']}/") == []
    assert scenes.deleting_scenes() == []
    assert store.list(f"tenants/acme/scenes/{ids['ready']}/input/") == [
        f"tenants/acme/scenes/{ids['ready']}/input/splat.ply"
    ]


def test_the_import_scenes_command_prints_its_counts(own_bucket: S3Server, records_db: Engine) -> None:
    store = own_bucket.store()
    ids = _old_release_bucket(store)
    env = {
        **os.environ,
        **own_bucket.env(),
        "BFIELDS_DATABASE_URL": records_db.url.render_as_string(hide_password=False),
    }
    command = [str(Path(sys.executable).parent / "bfields-service"), "import-scenes"]
    first = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
    assert first.returncode == 0, first.stderr
    assert "scenes: 4 imported (1 of them deleted" in first.stdout and "1 unreadable" in first.stdout
    assert scene_store(records_db).get("acme", ids["ready"]) is not None
    second = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
    assert second.returncode == 0, second.stderr
    assert "scenes: 0 imported (0 of them deleted, left to the sweeper), 4 already had a row" in second.stdout
