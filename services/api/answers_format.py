"""An answer listing as bytes: CSV (one header, then a line per answer, the lines written by the
database) or JSON Lines (one object per line), a page at a time, so an export of millions of
rows streams in the memory of one page (`records.answers` says why pages).

Why `format=` beside `Accept`: a browser link or `curl -o` cannot always set a header; the query
wins when both are given.
"""

from __future__ import annotations

import json
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


def csv_lines(chunks: Iterable[bytes]) -> Iterator[bytes]:
    """The CSV of a listing: the header (also for no rows), then `chunks`, lines already written
    as CSV by the database (`records.answers.batch_csv` says why there)."""
    yield (",".join(COLUMNS) + "\n").encode()
    yield from chunks


def jsonl_lines(pages: Iterable[list[dict[str, Any]]]) -> Iterator[bytes]:
    """One JSON object per row of `pages`, a chunk per page."""
    for page in pages:
        yield "".join(json.dumps(public(row), separators=(",", ":")) + "\n" for row in page).encode()
