"""An answer listing as bytes: CSV (one header, then a line per answer) or JSON Lines (one
object per line), written a page at a time, so an export of millions of rows streams in the
memory of one page (`records.answers` says why pages).

Why `format=` beside `Accept`: a browser link or `curl -o` cannot always set a header; the query
wins when both are given.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Iterable, Iterator
from typing import Any, Literal

from bayesian_fields_service.records.answers import COLUMNS

Format = Literal["json", "csv", "jsonl"]
MEDIA: dict[str, str] = {"csv": "text/csv; charset=utf-8", "jsonl": "application/x-ndjson"}
_ACCEPTED = (("text/csv", "csv"), ("application/x-ndjson", "jsonl"), ("application/jsonl", "jsonl"),
             ("application/json-lines", "jsonl"))  # fmt: skip


def chosen_format(query: Format | None, accept: str | None) -> Format:
    """The query's format, else the first streamed type `Accept` names, else a JSON page."""
    if query is not None:
        return query
    for media, name in _ACCEPTED:
        if media in (accept or ""):
            return name  # type: ignore[return-value]
    return "json"


def public(row: dict[str, Any]) -> dict[str, Any]:
    """A row as the API shows it: the listing's columns, in order, nothing internal."""
    return {c: row.get(c) for c in COLUMNS}


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, float) and not math.isfinite(value):
        return ""
    if isinstance(value, list):
        return json.dumps(value, separators=(",", ":"))
    return value


def csv_lines(pages: Iterable[list[dict[str, Any]]]) -> Iterator[bytes]:
    """The CSV of every row of `pages`: the header first (also for no rows), a chunk per page."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(COLUMNS)
    yield buffer.getvalue().encode()
    for page in pages:
        buffer.seek(0)
        buffer.truncate()
        writer.writerows([[_cell(row.get(c)) for c in COLUMNS] for row in page])
        yield buffer.getvalue().encode()


def jsonl_lines(pages: Iterable[list[dict[str, Any]]]) -> Iterator[bytes]:
    """One JSON object per row of `pages`, a chunk per page."""
    for page in pages:
        yield "".join(json.dumps(public(row), separators=(",", ":")) + "\n" for row in page).encode()
