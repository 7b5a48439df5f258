"""Scene routes: upload (one multipart request, or presigned multipart uploads), get, list, delete."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Body, HTTPException, Query, Request, Response, status
from fastapi.concurrency import run_in_threadpool

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import ArtifactNotFound, PrefixedStore
from bayesian_fields_core.scene.formats.registry import upload_description
from bayesian_fields_service import hooks
from bayesian_fields_service.api.archives import ArchiveLimits
from bayesian_fields_service.api.multipart import clean_filename, receive_multipart
from bayesian_fields_service.api.query import PAGE_LIMIT, SceneCursor
from bayesian_fields_service.api.scene_intake import (
    UploadedFile,
    alignment_wanted,
    assemble_scene,
    upload_scene_folder,
    validate_scene,
)
from bayesian_fields_service.api.scene_lifecycle import completion_claim, gone
from bayesian_fields_service.api.schemas import (
    CompleteRequest,
    PresignedUpload,
    Problem,
    SceneList,
    SceneRecord,
    SceneState,
    UploadPlan,
    UploadRequest,
)
from bayesian_fields_service.api.state import (
    BODY_ERRORS,
    ERRORS,
    AppState,
    State,
    Tenant,
    check_id,
    load_scene,
    scene_refusals,
)
from bayesian_fields_service.api.sweeper import upload_workdir
from bayesian_fields_service.common.scenes import SceneGone
from bayesian_fields_service.jobs.model import utcnow
from bayesian_fields_service.records.ids import new_id

router = APIRouter(prefix="/v1/scenes", tags=["scenes"])

_MULTIPART_SCHEMA = {
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "required": ["splat", "cameras", "images"],
                    "properties": {
                        "name": {"type": "string", "description": "Optional scene name."},
                        "alignment_check": {
                            "type": "string",
                            "enum": ["true", "false"],
                            "description": "false skips the geometric alignment check (default true).",
                        },
                        "splat": {
                            "type": "string",
                            "format": "binary",
                            "description": upload_description(),
                        },
                        "cameras": {
                            "type": "array",
                            "items": {"type": "string", "format": "binary"},
                            "description": "transforms.json, cameras.json, or COLMAP cameras + images "
                            "(.txt or .bin; points3D, frames, rigs optional).",
                        },
                        "images": {
                            "type": "array",
                            "items": {"type": "string", "format": "binary"},
                            "description": "The images as files, or ONE .zip/.tar(.gz) archive of them.",
                        },
                        "transform": {
                            "type": "string",
                            "format": "binary",
                            "description": "Optional: the splat's frame relative to the cameras, as nerfstudio's "
                            'dataparser_transforms.json or splat_transform.json ({"splat_to_camera": 4x4} '
                            'or gsplat\'s {"camera_to_splat": 4x4}).',
                        },
                    },
                }
            }
        },
    }
}


def _deleted(state: AppState, tenant: str, scene_id: str) -> bool:
    """Whether the scene's delete was acknowledged (its row says deleting, or is purged)."""
    return state.scenes.get(tenant, scene_id) is None


def _limits(state: AppState) -> ArchiveLimits:
    s = state.settings
    return ArchiveLimits(max_members=s.max_archive_members, max_bytes=s.max_archive_uncompressed_bytes)


def _ingest(
    state: AppState,
    tenant: str,
    scene_id: str,
    files: list[UploadedFile],
    work: Path,
    *,
    alignment: bool = True,
) -> tuple[int, int, dict]:
    """Assemble + validate in `work`, then upload to ``scenes/<id>/input/`` (blocking; threadpool)."""
    scene_dir = work / "scene"
    assemble_scene(files, scene_dir, _limits(state))
    summary = validate_scene(
        scene_dir,
        max_gaussians=state.settings.max_gaussians,
        max_frames=state.settings.max_frames,
        alignment=alignment,
    )
    n, size = upload_scene_folder(state.tenant(tenant), scene_dir, f"scenes/{scene_id}/input/")
    return n, size, summary


def _checked_name(name: str | None) -> str | None:
    """A scene's optional name as stored: at most 200 characters, no control characters (a NUL is
    refused by PostgreSQL's text, and none belongs in a name); 422 naming the field otherwise."""
    if not name:
        return None
    if len(name) > 200 or any(ord(c) < 0x20 or ord(c) == 0x7F for c in name):
        raise HTTPException(422, "name: at most 200 characters, and no control characters")
    return name


def _unprocessable(exc: InputError) -> HTTPException:
    return HTTPException(422, str(exc))


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    response_model=SceneRecord,
    summary="Upload a scene in one multipart request",
    openapi_extra=_MULTIPART_SCHEMA,
    responses={**BODY_ERRORS, 413: {"model": Problem}, 415: {"model": Problem}},
)
async def upload_scene(request: Request, tenant: Tenant, state: State) -> SceneRecord:
    """Stream the form to a temp folder (413 past BFIELDS_MAX_UPLOAD_BYTES), extract an image
    archive safely, validate everything, then store it. Nothing is stored when any check fails."""
    work = upload_workdir("upload")
    try:
        try:
            form = await receive_multipart(request, work / "parts", max_bytes=state.settings.max_upload_bytes)
            files = [UploadedFile(f.field, f.filename, f.path) for f in form.files]
            scene_id = new_id("s_")
            alignment = alignment_wanted(form.fields.get("alignment_check"))
            n, size, summary = await run_in_threadpool(
                _ingest, state, tenant, scene_id, files, work, alignment=alignment
            )
        except InputError as exc:
            raise _unprocessable(exc) from None
        now = utcnow()
        record = SceneRecord(
            id=scene_id, tenant=tenant, name=_checked_name(form.fields.get("name")), files=n, bytes=size,
            summary=summary, created_at=now, updated_at=now,
        )  # fmt: skip
        # the row last, once every file is in the bucket: a process killed while copying leaves
        # files no record names, which the sweeper removes once they are older than its age
        state.scenes.create(record)
        return record
    finally:
        shutil.rmtree(work, ignore_errors=True)


@router.post(
    "/uploads",
    status_code=status.HTTP_201_CREATED,
    response_model=UploadPlan,
    summary="Start a presigned upload (large captures go straight to the bucket)",
    responses={**BODY_ERRORS, 413: {"model": Problem}, 501: {"model": Problem}},
)
def start_upload(body: UploadRequest, tenant: Tenant, state: State) -> UploadPlan:
    """Returns presigned multipart PUT URLs per file; then call POST /v1/scenes/{id}/complete."""
    from bayesian_fields_service.storage.s3_store import plan_parts

    name = _checked_name(body.name)  # before anything is started in the bucket
    transfers = state.transfers(tenant)
    if transfers is None:
        raise HTTPException(status.HTTP_501_NOT_IMPLEMENTED, "the storage backend cannot presign URLs")
    total = sum(f.size for f in body.files)
    if total > state.settings.max_upload_bytes:
        raise HTTPException(
            status.HTTP_413_REQUEST_ENTITY_TOO_LARGE,
            f"upload of {total} bytes exceeds the limit of {state.settings.max_upload_bytes} bytes",
        )
    scene_id = new_id("s_")
    part_size = state.settings.s3_multipart_chunk_bytes
    uploads, pending = [], []
    try:
        for spec in body.files:
            name = clean_filename(spec.name, field_name=spec.field)
            key = f"scenes/{scene_id}/staging/{spec.field}/{name}"
            parts = plan_parts(spec.size, part_size)
            upload_id = transfers.start(key)
            urls = [transfers.part_link(key, upload_id, p.part_number) for p in parts]
            uploads.append(
                PresignedUpload(
                    field=spec.field, name=name, upload_id=upload_id, part_size=part_size, part_urls=urls
                )
            )
            pending.append(
                {"field": spec.field, "name": name, "key": key, "upload_id": upload_id, "size": spec.size}
            )
    except InputError as exc:
        raise _unprocessable(exc) from None
    now = utcnow()
    record = SceneRecord(
        id=scene_id, tenant=tenant, name=name, state=SceneState.uploading,
        pending_uploads=pending, created_at=now, updated_at=now,
    )  # fmt: skip
    state.scenes.create(record)  # after the uploads exist: the sweeper aborts those no row lists
    return UploadPlan(scene_id=scene_id, uploads=uploads, expires_in_s=state.settings.presign_expiry_s)


@router.post(
    "/{scene_id}/complete",
    response_model=SceneRecord,
    summary="Finish a presigned upload: assemble, validate, mark the scene ready",
    responses={**BODY_ERRORS, 409: {"model": Problem}, 413: {"model": Problem}},
)
def complete_upload(
    scene_id: str, tenant: Tenant, state: State, body: Annotated[CompleteRequest | None, Body()] = None
) -> SceneRecord:
    """Assemble the parts, validate, copy the scene to ``input/``, then (holding the scene's
    row, unless a delete came first) publish the ready record. See `scene_lifecycle`."""
    check_id("scene", scene_id, "s_")
    ts = state.tenant(tenant)
    with completion_claim(state.jobs.database, tenant, scene_id):
        record = load_scene(state, tenant, scene_id)  # under the claim: no other completion runs now
        if record.state != SceneState.uploading:
            raise HTTPException(
                status.HTTP_409_CONFLICT, f"scene {scene_id!r} is already {record.state.value}"
            )
        try:
            n, size, summary = _complete_files(state, tenant, record, body)
        except BaseException:
            if _deleted(state, tenant, scene_id):
                # a delete listed the scene's objects while this completion was still assembling
                # them: a file finished after that listing would stay behind. The delete is final
                # (the row's state), so everything under the scene is removed here, after the
                # last write.
                ts.delete_prefix(f"scenes/{scene_id}/")
            raise
        return _publish(state, tenant, record, n, size, summary)


def _complete_files(
    state: AppState, tenant: str, record: SceneRecord, body: CompleteRequest | None
) -> tuple[int, int, dict]:
    """Finish the multipart uploads, fetch, validate and copy the scene into ``input/``."""
    scene_id = record.id
    ts = state.tenant(tenant)
    transfers = state.transfers(tenant)
    if transfers is None:  # no multipart upload can have been started on this backend
        raise HTTPException(status.HTTP_501_NOT_IMPLEMENTED, "the storage backend cannot presign URLs")
    work = upload_workdir("complete")
    try:
        hooks.point("scene.complete.claimed", scene_id=scene_id)
        files = []
        for i, up in enumerate(record.pending_uploads):
            parts = None
            if body is not None and body.parts is not None and up["name"] in body.parts:
                parts = [p.model_dump() for p in body.parts[up["name"]]]
            try:
                transfers.complete(up["key"], up["upload_id"], parts)
            except (InputError, ArtifactNotFound) as exc:
                if _deleted(state, tenant, scene_id):
                    raise gone(scene_id) from None
                if _assembled(ts, up):  # an earlier, failed completion got this file done
                    pass
                elif isinstance(exc, ArtifactNotFound):  # the upload id is no longer known
                    raise HTTPException(
                        status.HTTP_409_CONFLICT,
                        f"the upload of {up['name']!r} no longer exists (aborted or expired)",
                    ) from None
                else:
                    raise _unprocessable(exc) from None
            actual = ts.size(up["key"])
            if actual != up["size"]:
                raise _unprocessable(
                    InputError(f"uploaded {actual} bytes, announced {up['size']}", source=up["name"])
                )
            local = work / "parts" / f"part-{i:05d}"
            ts.get_file(up["key"], local)
            files.append(UploadedFile(up["field"], up["name"], local))
        hooks.point("scene.complete.fetched", scene_id=scene_id)
        if _deleted(state, tenant, scene_id):  # deleted meanwhile: skip the copy (publishing checks again)
            raise gone(scene_id)
        try:
            alignment = body is None or body.alignment_check
            return _ingest(state, tenant, scene_id, files, work, alignment=alignment)
        except InputError as exc:
            raise _unprocessable(exc) from None
    except ArtifactNotFound:  # a staged object vanished: only a delete removes them
        if _deleted(state, tenant, scene_id):
            raise gone(scene_id) from None
        raise
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _assembled(ts: PrefixedStore, up: dict) -> bool:
    """Whether a file's multipart upload was already completed (by an earlier `complete` that
    failed on another file): its object exists with the announced size. Completing is then
    resumable instead of stuck on NoSuchUpload for good."""
    try:
        return ts.size(up["key"]) == up["size"]
    except ArtifactNotFound:
        return False


def _publish(
    state: AppState, tenant: str, record: SceneRecord, n: int, size: int, summary: dict
) -> SceneRecord:
    """Make the record ready unless the scene was deleted meanwhile (then remove the copy and
    answer 404): the state check and the change are one transaction holding the scene's row,
    which `delete` needs to mark the scene deleting."""
    scene_id = record.id
    ts = state.tenant(tenant)
    hooks.point("scene.complete.before_publish", scene_id=scene_id)
    with scene_refusals():  # published by another completion meanwhile: 409
        try:
            ready = state.scenes.publish_ready(
                tenant, scene_id, files=n, size=size, summary=summary,
                while_locked=lambda: hooks.point("scene.complete.publishing", scene_id=scene_id),
            )  # fmt: skip
        except SceneGone:  # deleted after the copy began: what it copied goes too
            ts.delete_prefix(f"scenes/{scene_id}/")
            raise gone(scene_id) from None
    ts.delete_prefix(f"scenes/{scene_id}/staging/")
    return ready


@router.get("/{scene_id}", response_model=SceneRecord, summary="Get a scene", responses=ERRORS)
def get_scene(scene_id: str, tenant: Tenant, state: State) -> SceneRecord:
    return load_scene(state, tenant, scene_id)


@router.get("", response_model=SceneList, summary="List scenes, newest first", responses=ERRORS)
def list_scenes(
    tenant: Tenant,
    state: State,
    limit: Annotated[int, Query(ge=1, le=PAGE_LIMIT)] = 50,
    cursor: SceneCursor = None,
) -> SceneList:
    items, next_cursor = state.scenes.list(tenant, limit, cursor)
    return SceneList(items=items, next_cursor=next_cursor)


@router.delete(
    "/{scene_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    response_class=Response,
    summary="Delete a scene (refused while jobs on it are queued or running)",
    responses={**ERRORS, 409: {"model": Problem}},
)
def delete_scene(scene_id: str, tenant: Tenant, state: State) -> Response:
    """Mark the scene deleting (one transaction on its row, refused while a job on it is queued
    or running), then abort its multipart uploads, remove its objects and drop its row. Once the
    mark is committed the scene is gone for every route, and a completion still running cannot
    publish it again (`scene_lifecycle`); what a failure here leaves behind, the sweeper removes."""
    check_id("scene", scene_id, "s_")
    with scene_refusals():
        record = state.scenes.mark_deleting(tenant, scene_id)
    hooks.point("scene.delete.marked", scene_id=scene_id)
    ts = state.tenant(tenant)
    transfers = state.transfers(tenant)
    if transfers is not None:  # a backend without them has no multipart upload to abort
        for up in record.pending_uploads:
            transfers.abort(up["key"], up["upload_id"])
    ts.delete_prefix(f"scenes/{scene_id}/")
    state.scenes.purge(tenant, scene_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
