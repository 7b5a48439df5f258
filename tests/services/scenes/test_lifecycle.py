"""The scenes domain's rules without a server (`scenes.lifecycle` over the in-memory records and
a folder bucket): what an upload must be to be stored, what completing a presigned upload
accepts, and the order a delete keeps (mark, then remove, then purge; busy while a job is
active). The same requests through HTTP, PostgreSQL and S3 are tests/services/api/test_uploads.py
and test_scene_races.py."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_service import hooks
from bayesian_fields_service.scenes.intake import UploadedFile
from bayesian_fields_service.scenes.lifecycle import FileToSend, Scenes
from bayesian_fields_service.scenes.model import DeletingScene, SceneRecord, SceneState
from bayesian_fields_service.scenes.refusals import (
    CompletionBusy,
    DeletedMeanwhile,
    NoDirectUploads,
    SceneBusy,
    SceneGone,
    SceneNotUploading,
    UploadTooLarge,
    UploadVanished,
)
from tests.services.scenes.conftest import SAMPLE
from tests.services.scenes.fakes import FolderMultipart, InMemorySceneRecords

TENANT = "acme"


def sample_parts() -> dict[tuple[str, str], bytes]:
    """The sample scene as (role, file name) -> bytes."""
    files = {("splat", "point_cloud.ply"): (SAMPLE / "point_cloud.ply").read_bytes(),
             ("cameras", "transforms.json"): (SAMPLE / "transforms.json").read_bytes()}  # fmt: skip
    for image in sorted((SAMPLE / "images").iterdir()):
        files[("images", image.name)] = image.read_bytes()
    return files


def received(work: Path, parts: dict[tuple[str, str], bytes]) -> list[UploadedFile]:
    """The files as the API's form receiver leaves them in `work/parts`."""
    (work / "parts").mkdir(parents=True)
    out = []
    for i, ((role, name), data) in enumerate(parts.items()):
        path = work / "parts" / f"part-{i:05d}"
        path.write_bytes(data)
        out.append(UploadedFile(role, name, path))
    return out


def keys(bucket: LocalStore, prefix: str = "tenants/") -> list[str]:
    return sorted(bucket.list(prefix))


def start_and_send(scenes: Scenes, multipart: FolderMultipart, parts: dict[tuple[str, str], bytes],
                   *, short: str | None = None) -> str:  # fmt: skip
    """A presigned upload of `parts`, every part sent (`short`: that file one byte short)."""
    started = scenes.start_upload(
        TENANT, "kitchen", [FileToSend(r, n, len(d)) for (r, n), d in parts.items()]
    )
    data = {name: d for (_, name), d in parts.items()}
    for up in started.uploads:
        body = data[up.name][:-1] if up.name == short else data[up.name]
        multipart.send_part(up.upload_id, 1, body)
    return started.scene_id


# a single-request upload


def test_an_upload_is_validated_then_stored_under_input_then_recorded(scenes: Scenes, bucket: LocalStore,
                                                                      tmp_path: Path) -> None:  # fmt: skip
    record = scenes.upload(TENANT, received(tmp_path, sample_parts()), {"name": "kitchen"}, tmp_path)
    assert record.state == SceneState.ready and record.name == "kitchen"
    assert record.summary["frames"] == len(list((SAMPLE / "images").iterdir()))
    stored = keys(bucket)
    assert stored and all(k.startswith(f"tenants/{TENANT}/scenes/{record.id}/input/") for k in stored)
    assert record.files == len(stored)
    assert scenes.get(TENANT, record.id) == record
    with pytest.raises(SceneGone):
        scenes.get("other-tenant", record.id)  # a tenant sees only its own


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda p: p.pop(("cameras", "transforms.json")), "cameras: no camera file"),
        (
            lambda p: p.update({("splat", "second.ply"): b"ply"}),
            "splat: expected exactly one splat file, got 2",
        ),
        (lambda p: p.update({("images", "notes.txt"): b"x"}), "images: 'notes.txt' is not an image"),
        (
            lambda p: p.update({("cameras", "poses.csv"): b"x"}),
            "cameras: 'poses.csv' is not a supported camera",
        ),
        (lambda p: p.update({("extra", "x.bin"): b"x"}), "form: unexpected form field 'extra'"),
    ],
)
def test_a_bad_upload_is_refused_naming_the_file_and_stores_nothing(
    scenes: Scenes, bucket: LocalStore, records: InMemorySceneRecords, tmp_path: Path,
    change: Callable[[dict], object], message: str,
) -> None:  # fmt: skip
    parts = sample_parts()
    change(parts)
    with pytest.raises(InputError, match=message.replace("(", r"\(")):
        scenes.upload(TENANT, received(tmp_path, parts), {}, tmp_path)
    assert keys(bucket) == [] and records.tables.scenes == {}


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"alignment_check": "maybe"}, "alignment_check: expected true or false, got 'maybe'"),
        ({"name": "a\x00b"}, "name: at most 200 characters, and no control characters"),
        ({"name": "n" * 201}, "name: at most 200 characters"),
    ],
)
def test_bad_form_fields_are_refused_and_no_row_is_written(
    scenes: Scenes, records: InMemorySceneRecords, tmp_path: Path, fields: dict[str, str], message: str
) -> None:
    with pytest.raises(InputError, match=message):
        scenes.upload(TENANT, received(tmp_path, sample_parts()), fields, tmp_path)
    assert records.tables.scenes == {}


# a presigned upload: start


def test_a_presigned_upload_needs_a_bucket_with_multipart_uploads(scenes: Scenes) -> None:
    with pytest.raises(NoDirectUploads, match="cannot presign"):
        scenes.start_upload(TENANT, None, [FileToSend("splat", "a.ply", 10)])
    with pytest.raises(NoDirectUploads):
        scenes.complete(TENANT, _uploading_scene(scenes))


def _uploading_scene(scenes: Scenes) -> str:
    from tests.services.scenes.conftest import T0

    record = SceneRecord(id="s_" + "0" * 21 + "9", tenant=TENANT, state=SceneState.uploading,
                         created_at=T0, updated_at=T0)  # fmt: skip
    scenes.rows.create(record)
    return record.id


def test_a_presigned_upload_over_the_limit_starts_nothing(
    presigned: Scenes, multipart: FolderMultipart, records: InMemorySceneRecords
) -> None:
    limit = presigned.settings.max_upload_bytes
    with pytest.raises(
        UploadTooLarge, match=f"upload of {limit + 1} bytes exceeds the limit of {limit} bytes"
    ):
        presigned.start_upload(
            TENANT, None, [FileToSend("images", "a.zip", limit - 9), FileToSend("splat", "s.ply", 10)]
        )
    assert multipart.uploads == {} and records.tables.scenes == {}


def test_a_started_upload_is_an_uploading_row_listing_each_file_under_staging(
    presigned: Scenes, multipart: FolderMultipart
) -> None:
    started = presigned.start_upload(
        TENANT, "kitchen", [FileToSend("splat", "dir/s.ply", 10), FileToSend("images", "a.zip", 20)]
    )
    assert [(u.field, u.name) for u in started.uploads] == [("splat", "s.ply"), ("images", "a.zip")]
    record = presigned.get(TENANT, started.scene_id)
    assert record.state == SceneState.uploading
    assert record.name == "kitchen"  # the scene's name, not its last file's
    assert [p["key"] for p in record.pending_uploads] == [
        f"scenes/{started.scene_id}/staging/splat/s.ply", f"scenes/{started.scene_id}/staging/images/a.zip"
    ]  # fmt: skip
    assert {p["upload_id"] for p in record.pending_uploads} == set(multipart.uploads)


def test_a_hidden_file_name_is_refused_before_any_row(
    presigned: Scenes, records: InMemorySceneRecords
) -> None:
    with pytest.raises(InputError, match="images: unusable file name '.hidden'"):
        presigned.start_upload(TENANT, None, [FileToSend("images", ".hidden", 10)])
    assert records.tables.scenes == {}


# a presigned upload: complete


def test_completion_validates_copies_to_input_publishes_and_clears_staging(
    presigned: Scenes, multipart: FolderMultipart, bucket: LocalStore
) -> None:
    scene_id = start_and_send(presigned, multipart, sample_parts())
    ready = presigned.complete(TENANT, scene_id)
    assert ready.state == SceneState.ready and ready.pending_uploads == [] and ready.name == "kitchen"
    stored = keys(bucket)
    assert stored and all(k.startswith(f"tenants/{TENANT}/scenes/{scene_id}/input/") for k in stored)
    with pytest.raises(SceneNotUploading, match=f"scene '{scene_id}' is already ready"):
        presigned.complete(TENANT, scene_id)


def test_a_file_shorter_than_announced_is_refused_and_the_scene_stays_uploading(
    presigned: Scenes, multipart: FolderMultipart
) -> None:
    parts = sample_parts()
    scene_id = start_and_send(presigned, multipart, parts, short="transforms.json")
    size = len(parts[("cameras", "transforms.json")])
    with pytest.raises(InputError, match=f"transforms.json: uploaded {size - 1} bytes, announced {size}"):
        presigned.complete(TENANT, scene_id)
    assert presigned.get(TENANT, scene_id).state == SceneState.uploading


def test_an_aborted_upload_is_a_conflict_naming_the_file(
    presigned: Scenes, multipart: FolderMultipart
) -> None:
    scene_id = start_and_send(presigned, multipart, sample_parts())
    up = presigned.get(TENANT, scene_id).pending_uploads[0]
    multipart.uploads.pop(up["upload_id"])  # expired in the bucket
    with pytest.raises(UploadVanished, match=f"the upload of '{up['name']}' no longer exists"):
        presigned.complete(TENANT, scene_id)


def test_completion_resumes_a_file_an_earlier_completion_finished(
    presigned: Scenes, multipart: FolderMultipart, bucket: LocalStore
) -> None:
    scene_id = start_and_send(presigned, multipart, sample_parts())
    up = presigned.get(TENANT, scene_id).pending_uploads[0]
    multipart.complete_multipart_upload(f"tenants/{TENANT}/{up['key']}", up["upload_id"])  # the object exists
    assert presigned.complete(TENANT, scene_id).state == SceneState.ready


def test_one_completion_at_a_time(
    presigned: Scenes, multipart: FolderMultipart, records: InMemorySceneRecords
) -> None:
    scene_id = start_and_send(presigned, multipart, sample_parts())
    with (
        records.completion_claim(TENANT, scene_id),
        pytest.raises(CompletionBusy, match="already being completed"),
    ):
        presigned.complete(TENANT, scene_id)
    assert presigned.complete(TENANT, scene_id).state == SceneState.ready  # the claim was given back


def test_a_delete_during_completion_wins_and_the_completion_removes_what_it_copied(
    presigned: Scenes, multipart: FolderMultipart, bucket: LocalStore, monkeypatch: pytest.MonkeyPatch
) -> None:
    scene_id = start_and_send(presigned, multipart, sample_parts())
    monkeypatch.setattr(hooks.REGISTRY, "_points", {})
    hooks.REGISTRY.on(
        "scene.complete.before_publish", lambda scene_id: presigned.rows.mark_deleting(TENANT, scene_id)
    )
    with pytest.raises(DeletedMeanwhile, match=r"not found \(it was deleted\)"):
        presigned.complete(TENANT, scene_id)
    assert keys(bucket) == []  # input/ and staging/ both gone
    with pytest.raises(SceneGone):
        presigned.get(TENANT, scene_id)


# delete


def test_a_scene_with_an_active_job_is_busy_and_keeps_everything(
    scenes: Scenes, records: InMemorySceneRecords, bucket: LocalStore, tmp_path: Path
) -> None:
    record = scenes.upload(TENANT, received(tmp_path, sample_parts()), {}, tmp_path)
    records.tables.active_jobs[(TENANT, record.id)] = ("j_1", "running")
    before = keys(bucket)
    with pytest.raises(SceneBusy, match=f"scene '{record.id}' has running job j_1"):
        scenes.delete(TENANT, record.id)
    assert scenes.get(TENANT, record.id) == record and keys(bucket) == before


def test_a_delete_removes_objects_uploads_answers_and_the_row(
    presigned: Scenes, multipart: FolderMultipart, records: InMemorySceneRecords, bucket: LocalStore
) -> None:
    scene_id = start_and_send(presigned, multipart, sample_parts())
    pending = {p["upload_id"] for p in presigned.get(TENANT, scene_id).pending_uploads}
    records.tables.answers[(TENANT, scene_id)] = ["an answer"]
    presigned.delete(TENANT, scene_id)
    assert set(multipart.aborted) == pending and multipart.uploads == {}
    assert keys(bucket) == [] and records.tables.scenes == {} and records.tables.answers == {}
    with pytest.raises(SceneGone):
        presigned.delete(TENANT, scene_id)


class _StuckBucket(LocalStore):
    """A folder whose deletes fail (an outage after the delete's mark committed)."""

    def delete_prefix(self, prefix: str) -> None:
        raise OSError("the bucket is unavailable")


def test_a_delete_marks_first_so_a_failure_after_the_mark_leaves_the_scene_gone_for_the_sweeper(
    scenes: Scenes, records: InMemorySceneRecords, tmp_path: Path
) -> None:
    record = scenes.upload(TENANT, received(tmp_path / "w", sample_parts()), {}, tmp_path / "w")
    stuck = Scenes(scenes.settings, _StuckBucket(scenes.bucket.root), scenes.rows, scenes.new_id)  # type: ignore[attr-defined]
    with pytest.raises(OSError):
        stuck.delete(TENANT, record.id)
    with pytest.raises(SceneGone):
        scenes.get(TENANT, record.id)  # gone for every reader from the mark on
    assert scenes.rows.deleting_scenes() == [DeletingScene(TENANT, record.id, [])]  # the sweeper's work
    assert scenes.page(TENANT, 10, None) == ([], None)


def test_scenes_page_newest_first(scenes: Scenes, tmp_path: Path) -> None:
    made = [scenes.upload(TENANT, received(tmp_path / str(i), sample_parts()), {}, tmp_path / str(i)).id
            for i in range(3)]  # fmt: skip
    first, cursor = scenes.page(TENANT, 2, None)
    assert [r.id for r in first] == made[::-1][:2] and cursor == made[1]
    rest, end = scenes.page(TENANT, 2, cursor)
    assert [r.id for r in rest] == [made[0]] and end is None
