"""Scene routes: upload (one multipart request, or presigned multipart uploads), get, list, delete.

HTTP only: each route parses the request, calls the scenes domain (`scenes.lifecycle.Scenes`)
and shapes the answer; the domain's refusals are answered by `api.edge` (404, 409, 413, 422, 501).
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body, Query, Request, Response, status
from fastapi.concurrency import run_in_threadpool

from bayesian_fields_core.scene.formats.registry import upload_description
from bayesian_fields_service.api.multipart import receive_multipart
from bayesian_fields_service.api.query import PAGE_LIMIT, SceneCursor
from bayesian_fields_service.api.schemas import (
    CompleteRequest,
    PresignedUpload,
    Problem,
    SceneList,
    SceneRecord,
    UploadPlan,
    UploadRequest,
)
from bayesian_fields_service.api.state import BODY_ERRORS, ERRORS, State, Tenant, check_id
from bayesian_fields_service.scenes.intake import UploadedFile
from bayesian_fields_service.scenes.lifecycle import FileToSend

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
    with state.scenes.workdir("upload") as work:
        form = await receive_multipart(request, work / "parts", max_bytes=state.settings.max_upload_bytes)
        files = [UploadedFile(f.field, f.filename, f.path) for f in form.files]
        return await run_in_threadpool(state.scenes.upload, tenant, files, form.fields, work)


@router.post(
    "/uploads",
    status_code=status.HTTP_201_CREATED,
    response_model=UploadPlan,
    summary="Start a presigned upload (large captures go straight to the bucket)",
    responses={**BODY_ERRORS, 413: {"model": Problem}, 501: {"model": Problem}},
)
def start_upload(body: UploadRequest, tenant: Tenant, state: State) -> UploadPlan:
    """Returns presigned multipart PUT URLs per file; then call POST /v1/scenes/{id}/complete."""
    files = [FileToSend(f.field, f.name, f.size) for f in body.files]
    started = state.scenes.start_upload(tenant, body.name, files)
    uploads = [
        PresignedUpload(
            field=u.field, name=u.name, upload_id=u.upload_id, part_size=u.part_size, part_urls=u.part_urls
        )
        for u in started.uploads
    ]
    return UploadPlan(scene_id=started.scene_id, uploads=uploads, expires_in_s=started.expires_in_s)


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
    row, unless a delete came first) publish the ready record (`scenes.lifecycle`)."""
    check_id("scene", scene_id, "s_")
    parts = None
    if body is not None and body.parts is not None:
        parts = {name: [p.model_dump() for p in listed] for name, listed in body.parts.items()}
    alignment = body is None or body.alignment_check
    return state.scenes.complete(tenant, scene_id, parts, alignment=alignment)


@router.get("/{scene_id}", response_model=SceneRecord, summary="Get a scene", responses=ERRORS)
def get_scene(scene_id: str, tenant: Tenant, state: State) -> SceneRecord:
    check_id("scene", scene_id, "s_")
    return state.scenes.get(tenant, scene_id)


@router.get("", response_model=SceneList, summary="List scenes, newest first", responses=ERRORS)
def list_scenes(
    tenant: Tenant,
    state: State,
    limit: Annotated[int, Query(ge=1, le=PAGE_LIMIT)] = 50,
    cursor: SceneCursor = None,
) -> SceneList:
    items, next_cursor = state.scenes.page(tenant, limit, cursor)
    return SceneList(items=items, next_cursor=next_cursor)


@router.delete(
    "/{scene_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    response_class=Response,
    summary="Delete a scene (refused while jobs on it are queued or running)",
    responses={**ERRORS, 409: {"model": Problem}},
)
def delete_scene(scene_id: str, tenant: Tenant, state: State) -> Response:
    """Mark the scene deleting (refused while a job on it is queued or running), then remove its
    uploads, objects and row (`scenes.lifecycle`): once marked it is gone for every route."""
    check_id("scene", scene_id, "s_")
    state.scenes.delete(tenant, scene_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
