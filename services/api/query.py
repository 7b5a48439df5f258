"""The query parameters of the routes, each checked at the edge before it reaches the records.

Why here: a value PostgreSQL or Python cannot hold (a cursor past a bigint, a date whose next day
is past year 9999, a NUL in text) was answered 500, and a filter that could never match (a scene
id of another shape) was answered 200 with an empty page, which hides a client's mistake. Each
type below refuses such a value with 422 naming the parameter (FastAPI's validation error, in the
`Problem` body of `api.edge`), so a route only ever sees values the records can take.
"""

from __future__ import annotations

from datetime import date
from typing import Annotated

from fastapi import Query
from pydantic import AfterValidator, StringConstraints

from bayesian_fields_service.records.ids import id_pattern

#: The most items a listing route answers in one page (its `limit`).
PAGE_LIMIT = 500
#: A position cursor is a job's position in its batch, an `integer` column (a batch holds at most
#: `max_batch_jobs` of them), and a page reads positions n to n + limit + 1: the largest n leaves
#: that range inside the column's type (2**31 - 1), which is also far below 2**63.
MAX_POSITION = 2**31 - 1 - (PAGE_LIMIT + 1)
#: The years a usage period may name: the service's records all fall inside, and a day's
#: arithmetic (the next day, the 1st of the month) cannot leave Python's date range.
YEARS = (2000, 2999)


def _position(value: str | None) -> int | None:
    """A position cursor as an int, refused past the column's range (the pattern already holds it
    to ASCII digits: ``'²'`` and Arabic-Indic digits pass `str.isdigit`, not the pattern)."""
    if value is None:
        return None
    number = int(value)
    if number > MAX_POSITION:
        raise ValueError(
            f"a position cursor is at most {MAX_POSITION}; send next_cursor of the previous page"
        )
    return number


def _in_years(value: date | None) -> date | None:
    if value is not None and not YEARS[0] <= value.year <= YEARS[1]:
        raise ValueError(f"a day between {YEARS[0]}-01-01 and {YEARS[1]}-12-31 (YYYY-MM-DD)")
    return value


def id_filter(prefix: str, what: str) -> Query:  # type: ignore[valid-type]
    """A query parameter that must be one of the service's ids (`records.ids.id_pattern`)."""
    return Query(pattern=id_pattern(prefix), description=what)


#: `GET /v1/jobs?scene_id=`: a scene id, or no filter.
SceneFilter = Annotated[str | None, id_filter("s_", "Only the jobs of this scene (a scene id)")]
#: `GET /v1/jobs?cursor=`: the last job id of the previous page.
JobCursor = Annotated[str | None, id_filter("j_", "next_cursor of the previous page (a job id)")]
#: `GET /v1/scenes?cursor=`: the last scene id of the previous page.
SceneCursor = Annotated[str | None, id_filter("s_", "next_cursor of the previous page (a scene id)")]
#: `GET /v1/batches/{id}/jobs?cursor=`: a position in the batch, ASCII digits up to `MAX_POSITION`.
PositionCursor = Annotated[
    str | None,
    Query(pattern=r"^[0-9]{1,10}$", description="next_cursor of the previous page (a position)"),
    AfterValidator(_position),
]
#: A day of a usage period (YYYY-MM-DD, within `YEARS`).
Day = Annotated[date | None, AfterValidator(_in_years)]


# ---- answers (issue 42) ------------------------------------------------------------------------
#: The longest task text or scene name a filter may give: longer than any stored one can be
#: (`max_task_chars`, a scene name's 255), so a longer one is a client's mistake, not a miss.
FILTER_CHARS = 1000
#: A task's index and an answer's rank in a cursor: a job holds at most `max_tasks` tasks and
#: `top_k` objects per task, both far below this.
MAX_RANK = 100_000


def _printable(value: str | None) -> str | None:
    """Text without control characters (a NUL cannot reach PostgreSQL; a newline in a filter is
    never a stored task's), and not blank."""
    if value is None:
        return None
    if not value.strip():
        raise ValueError("must not be blank")
    if any(ord(c) < 32 or ord(c) == 127 for c in value):
        raise ValueError("must not contain control characters (NUL, newline, tab, ...)")
    return value


def _answer_cursor(value: str | None) -> tuple[int, int, int] | None:
    """`position.task_index.rank` of the previous page's last answer."""
    if value is None:
        return None
    position, index, rank = (int(v) for v in value.split("."))
    if position > MAX_POSITION or index > MAX_RANK or rank > MAX_RANK:
        raise ValueError("not a cursor this service wrote; send next_cursor of the previous page")
    return position, index, rank


def _fleet_cursor(value: str | None) -> tuple[str, int] | None:
    """`job_id.rank` of the previous page's last answer."""
    if value is None:
        return None
    job_id, rank = value.split(".")
    if int(rank) > MAX_RANK:
        raise ValueError("not a cursor this service wrote; send next_cursor of the previous page")
    return job_id, int(rank)


#: A task filter: its exact text or a unique part of it (as `bfields export --task`).
TaskText = Annotated[
    str | None,
    Query(max_length=FILTER_CHARS, description="the task's text, or a unique part of it ('mug')"),
    AfterValidator(_printable),
]
#: A scene filter of the answer routes: a scene's name or id.
SceneName = Annotated[
    str | None,
    Query(max_length=FILTER_CHARS, description="only this scene's answers (its name or id)"),
    AfterValidator(_printable),
]
#: The least probability an answer may have, in [0, 1].
MinProbability = Annotated[
    float | None,
    Query(ge=0.0, le=1.0, allow_inf_nan=False, description="answers at least this probable (0-1)"),
]
#: The greatest rank kept (1 = only each task's best object).
MaxRank = Annotated[int | None, Query(ge=1, le=MAX_RANK, description="answers up to this rank (1 = best)")]
#: `GET /v1/batches/{id}/answers?cursor=`.
AnswerCursor = Annotated[
    str | None,
    Query(pattern=r"^[0-9]{1,10}\.[0-9]{1,6}\.[0-9]{1,6}$", description="next_cursor of the previous page"),
    AfterValidator(_answer_cursor),
]
#: `GET /v1/answers?cursor=`.
FleetCursor = Annotated[
    str | None,
    Query(pattern=id_pattern("j_")[:-1] + r"\.[0-9]{1,6}$", description="next_cursor of the previous page"),
    AfterValidator(_fleet_cursor),
]
#: `GET /v1/answers?batch=`: batch ids (repeat the parameter), at most 100.
BatchIds = Annotated[
    list[Annotated[str, StringConstraints(pattern=id_pattern("b_"))]] | None,
    Query(max_length=100, description="only these batches' jobs (repeat: batch=b_..&batch=b_..)"),
]
