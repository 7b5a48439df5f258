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
from pydantic import AfterValidator

from bayesian_fields_service.common.jobs import id_pattern

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
    """A query parameter that must be one of the service's ids (`common.jobs.id_pattern`)."""
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
