"""Answer routes (issue 42): a batch's answers as one table (paged, or streamed as CSV / JSON Lines)
and one task's answers across the tenant's fleet.

HTTP only: the rows are written with each job's success (`jobs.answers`) and read through the
jobs domain's `Answers` (`state.answers`, over the statements of `records.answers`); every query
value is checked here (`api.query`) and a refusal names its parameter (422). A batch of another
tenant is 404, as everywhere.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated, Any, cast

from fastapi import APIRouter, Header, Query
from fastapi.exceptions import RequestValidationError
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, Field

from bayesian_fields_service.api.answers_format import (
    MEDIA,
    Format,
    chosen_format,
    csv_lines,
    jsonl_lines,
    public,
)
from bayesian_fields_service.api.query import (
    PAGE_LIMIT,
    AnswerCursor,
    BatchIds,
    FleetCursor,
    MaxRank,
    MinProbability,
    SceneName,
    TaskText,
)
from bayesian_fields_service.api.state import ERRORS, AppState, State, Tenant
from bayesian_fields_service.jobs.answers import AnswerFilter

router = APIRouter(prefix="/v1", tags=["answers"])

#: Rows per read of a streamed JSON Lines export: the API's memory per export is about one page.
EXPORT_PAGE = 1000
#: Jobs per read of a streamed CSV export (written by the database: 8 tasks x 5 objects a job
#: are about 20 kB of CSV, so a page is a few MB).
EXPORT_JOBS = 200


class Answer(BaseModel):
    """One answer: a task's ranked object (found), or the task's "not found" row (rank 0)."""

    job_id: str
    scene_id: str
    scene_name: str | None
    task: str
    task_index: int
    rank: int = Field(description="1 = the task's best object; 0 on a 'not found' row")
    found: bool
    object_id: int | None
    content_key: str | None
    probability: float | None
    best_view_score: float | None = Field(
        description="the object's best single view (format 1.6; 'peak' before)"
    )
    score: float | None = Field(
        description="what the objects were ranked by (ranked_by: evidence by default)"
    )
    ranked_by: str | None
    num_gaussians: int | None
    frame: str | None = Field(description="the frame of the coordinates: world, capture or splat")
    centre_x: float | None
    centre_y: float | None
    centre_z: float | None
    extent_x: float | None
    extent_y: float | None
    extent_z: float | None
    rotation: list[list[float]] | None
    centroid_x: float | None
    centroid_y: float | None
    centroid_z: float | None
    preview: str | None = Field(description="the task's preview image, relative to the job")
    not_found_reason: str | None
    preview_url: str | None = Field(None, description="a link to the preview (presigned, or an API path)")


class AnswerPage(BaseModel):
    task: str | None = Field(description="the task the filter resolved to (its exact text), or null")
    items: list[Answer]
    next_cursor: str | None


class FleetPage(BaseModel):
    task: str
    asked: int = Field(description="scenes whose latest succeeded job asked the task")
    found: int
    not_found: int = Field(description="of those, the scenes that answered it 'not found'")
    items: list[Answer]
    next_cursor: str | None


def _refuse(field: str, msg: str) -> RequestValidationError:
    return RequestValidationError([{"loc": ("query", field), "msg": msg, "type": "value_error"}])


def _resolve_task(state: AppState, tenant: str, part: str | None, batch_id: str | None) -> str | None:
    """The one answered task `part` names (exact text, else a unique part, case-insensitive, as
    `bfields export --task`); 422 naming `task` when none or several do."""
    if part is None:
        return None
    found = state.answers.matching_tasks(tenant, part, batch_id=batch_id)
    if len(found) == 1:
        return found[0]
    if not found and batch_id is None:
        return part  # no scene of the tenant asked it: the fleet's answer is "0 asked", not an error
    if not found:
        raise _refuse(
            "task", f"no task of this batch's answers matches {part!r}; give its text or a part of it"
        )
    listed = "; ".join(repr(t) for t in found)
    raise _refuse("task", f"{part!r} matches several tasks ({listed}); give more of its text")


def _with_links(state: AppState, tenant: str, rows: list[dict[str, Any]]) -> list[Answer]:
    transfers = state.transfers(tenant)
    links: dict[str, str] = {}  # a job's task preview is shared by its ranks: one presign each
    out = []
    for row in rows:
        shown = public(row)
        if row.get("preview"):
            key = f"jobs/{row['job_id']}/{row['preview']}"
            if key not in links:
                links[key] = (
                    transfers.link(key)
                    if transfers is not None
                    else f"/v1/jobs/{row['job_id']}/artifacts/{row['preview']}"
                )
            shown["preview_url"] = links[key]
        out.append(Answer(**shown))
    return out


@router.get(
    "/batches/{batch_id}/answers",
    response_model=AnswerPage,
    summary="A batch's answers: a page (JSON), or the whole table streamed as CSV or JSON Lines",
    tags=["batches"],
    responses={
        **ERRORS,
        200: {
            "content": {"text/csv": {}, "application/x-ndjson": {}},
            "description": "a page, or the stream",
        },
    },
)
def batch_answers(
    batch_id: str,
    tenant: Tenant,
    state: State,
    task: TaskText = None,
    min_probability: MinProbability = None,
    max_rank: MaxRank = None,
    found: Annotated[
        bool | None, Query(description="true: found answers only; false: 'not found' rows")
    ] = None,
    scene: SceneName = None,
    format: Annotated[
        Format | None, Query(description="json (a page), csv or jsonl (everything, streamed)")
    ] = None,  # noqa: A002
    limit: Annotated[int, Query(ge=1, le=PAGE_LIMIT)] = 100,
    cursor: AnswerCursor = None,
    accept: Annotated[str | None, Header(include_in_schema=False)] = None,
) -> Any:
    """In the batch's submission order, then each job's task order and rank: a stable order, so
    `next_cursor` pages never skip or repeat a row while other jobs finish."""
    batch = state.service.batch(tenant, batch_id)
    wanted = AnswerFilter(
        task=_resolve_task(state, tenant, task, batch.id), min_probability=min_probability,
        max_rank=max_rank, found=found, scene=scene,
    )  # fmt: skip
    kind = chosen_format(format, accept)
    after = cast("tuple[int, int, int] | None", cursor)  # parsed by AnswerCursor's validator
    if kind != "json":
        if kind == "csv":
            lines = csv_lines(state.answers.batch_csv(tenant, batch.id, wanted, after=after,
                                                      jobs_per_page=EXPORT_JOBS))  # fmt: skip
        else:
            lines = jsonl_lines(_pages(state, tenant, batch.id, wanted, after))
        name = f"{batch.id}-answers.{kind}"
        return StreamingResponse(lines, media_type=MEDIA[kind],
                                 headers={"Content-Disposition": f'attachment; filename="{name}"'})  # fmt: skip
    rows = state.answers.batch_page(tenant, batch.id, wanted, after=after, limit=limit + 1)
    nxt = None
    if len(rows) > limit:
        last = rows[limit - 1]
        nxt = f"{last['position']}.{last['task_index']}.{last['rank']}"
    return AnswerPage(task=wanted.task, items=_with_links(state, tenant, rows[:limit]), next_cursor=nxt)


def _pages(
    state: AppState,
    tenant: str,
    batch_id: str,
    wanted: AnswerFilter,
    after: tuple[int, int, int] | None,
) -> Iterator[list[dict[str, Any]]]:
    """Every matching row, `EXPORT_PAGE` at a time (each page a fresh indexed read)."""
    while True:
        page = state.answers.batch_page(tenant, batch_id, wanted, after=after, limit=EXPORT_PAGE)
        if page:
            yield page
        if len(page) < EXPORT_PAGE:
            return
        last = page[-1]
        after = (last["position"], last["task_index"], last["rank"])


@router.get(
    "/answers",
    response_model=FleetPage,
    summary="One task's answers across the tenant's fleet: each scene's latest succeeded job that "
    "asked it, ranked by probability",
    responses=ERRORS,
)
def fleet_answers(
    tenant: Tenant,
    state: State,
    task: TaskText = None,
    batch: BatchIds = None,
    min_probability: MinProbability = None,
    all_ranks: Annotated[bool, Query(description="true: every ranked object, not each scene's best")] = False,
    limit: Annotated[int, Query(ge=1, le=PAGE_LIMIT)] = 100,
    cursor: FleetCursor = None,
) -> FleetPage:
    if task is None:
        raise _refuse("task", "give the task to search for: task=<its text or a unique part of it>")
    for batch_id in batch or []:
        state.service.batch(tenant, batch_id)  # another tenant's (or no) batch: 404
    exact = _resolve_task(state, tenant, task, None)
    assert exact is not None
    after = None
    if cursor is not None:
        at = state.answers.answer_probability(tenant, exact, *cursor)
        if at is None:
            raise _refuse("cursor", "the cursor's answer is gone; start again without a cursor")
        after = (at, *cursor)
    got = state.answers.fleet(tenant, exact, batch_ids=batch or [], min_probability=min_probability,
                              best_only=not all_ranks, after=after, limit=limit + 1)  # fmt: skip
    rows = got.rows
    nxt = f"{rows[limit - 1]['job_id']}.{rows[limit - 1]['rank']}" if len(rows) > limit else None
    return FleetPage(task=exact, asked=got.asked, found=got.asked - got.not_found, not_found=got.not_found,
                     items=_with_links(state, tenant, rows[:limit]), next_cursor=nxt)  # fmt: skip
