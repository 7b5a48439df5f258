"""The one error body of the API: an RFC 9457 problem (``application/problem+json``).

Why one builder: errors are answered in several places (the exception handlers of `api.edge`, and
the pure ASGI middlewares that answer before any route: the UTF-8 guard, the tenant gate's 429,
the body deadline's 408). Each builds its answer with `problem_response`, so every error carries
the same members: ``type`` (the kind's URI, `api.problem_types`), ``title``, ``status``,
``detail`` (one readable line, as before), ``instance`` (the request's path) and, for request
validation, ``errors`` (one entry per refused field, as before), so clients that read ``detail``
(the CLI, the /ui pages) and ``errors`` keep working. A 429 or 503 without ``Retry-After`` is a
programming error here, not an answer.

`describe_problems` makes the OpenAPI document say the same: every 4xx/5xx response of every
operation is a `Problem` as ``application/problem+json``.
"""

from __future__ import annotations

import html
from collections.abc import Callable, Mapping
from typing import Any

from fastapi import FastAPI
from fastapi.responses import HTMLResponse, JSONResponse

from bayesian_fields_service.api.problem_types import KINDS, PAGE_PATH, ProblemType
from bayesian_fields_service.sanitize.text import scrub_text

MEDIA_TYPE = "application/problem+json"
#: Statuses whose answer must say when to come back.
RETRY_STATUSES = frozenset({429, 503})


class ProblemJSONResponse(JSONResponse):
    media_type = MEDIA_TYPE


def problem_body(
    kind: ProblemType | str,
    detail: str,
    instance: str,
    *,
    status: int | None = None,
    errors: list[dict[str, Any]] | None = None,
    extensions: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The problem's members; `status` defaults to the kind's (``http-error`` needs one)."""
    kind = KINDS[kind] if isinstance(kind, str) else kind
    code = status or kind.status
    if not 400 <= code <= 599:
        raise ValueError(f"problem {kind.slug!r} needs an error status, not {code}")
    body: dict[str, Any] = {
        "type": kind.uri,
        "title": kind.title,
        "status": code,
        "detail": scrub_text(detail),
        "instance": scrub_text(instance),
    }
    if errors is not None:
        body["errors"] = errors
    body.update(extensions or {})
    return body


def problem_response(
    kind: ProblemType | str,
    detail: str,
    instance: str,
    *,
    status: int | None = None,
    errors: list[dict[str, Any]] | None = None,
    headers: Mapping[str, str] | None = None,
    extensions: Mapping[str, Any] | None = None,
) -> JSONResponse:
    """The answer of an error (module docstring); a 429 or 503 must carry ``Retry-After``."""
    body = problem_body(kind, detail, instance, status=status, errors=errors, extensions=extensions)
    if body["status"] in RETRY_STATUSES and not any(k.lower() == "retry-after" for k in headers or {}):
        raise ValueError(f"a {body['status']} answer needs Retry-After ({body['type']})")
    return ProblemJSONResponse(body, status_code=body["status"], headers=dict(headers) if headers else None)


def install_problem_page(app: FastAPI) -> None:
    """Serve `PAGE_PATH`: every kind as a section whose id is its slug, so each ``type`` resolves
    (against the API's own URL) to the section that explains it."""
    sections = "".join(
        f'<section id="{k.slug}"><h2>{k.slug}</h2><p><b>{k.status or "4xx/5xx"}: {html.escape(k.title)}.</b> '
        f"{html.escape(k.meaning)}</p><p><i>Fix:</i> {html.escape(k.fix)}</p></section>"
        for k in KINDS.values()
    )
    page = (
        '<!doctype html><html lang="en"><head><meta charset="utf-8"><title>Bayesian Fields API errors'
        f"</title></head><body><h1>Errors of the Bayesian Fields API</h1>{sections}</body></html>"
    )

    @app.get(PAGE_PATH, include_in_schema=False)
    def errors_page() -> HTMLResponse:
        return HTMLResponse(page)


_PROBLEM_REF = {"$ref": "#/components/schemas/Problem"}
#: The error models FastAPI may have written into a response (its own, for a route without a 422).
_ERROR_MODELS = ("/Problem", "/HTTPValidationError")
_RETRY_AFTER = {"schema": {"type": "integer"}, "description": "Seconds to wait before retrying"}


def describe_problems(app: FastAPI) -> None:
    """Make the OpenAPI document say what the handlers answer: every 4xx/5xx response of every
    operation is a `Problem` as ``application/problem+json`` (FastAPI writes the declared model as
    ``application/json``, and its own validation schema where a route declares no 422), each 429
    and 503 with ``Retry-After``. A response declared with another model (``/readyz``'s 503 is its
    health report) keeps it."""
    build: Callable[[], dict[str, Any]] = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is not None:
            return app.openapi_schema
        document = build()
        for methods in document.get("paths", {}).values():
            for op in methods.values():
                for code, response in op.get("responses", {}).items():
                    if not code.isdigit() or int(code) < 400:
                        continue
                    schema = response.get("content", {}).get("application/json", {}).get("schema", {})
                    if not response.get("content") or schema.get("$ref", "").endswith(_ERROR_MODELS):
                        response["content"] = {MEDIA_TYPE: {"schema": dict(_PROBLEM_REF)}}
                    if int(code) in RETRY_STATUSES:
                        response.setdefault("headers", {}).setdefault("Retry-After", _RETRY_AFTER)
        schemas = document.get("components", {}).get("schemas", {})
        for unused in ("HTTPValidationError", "ValidationError"):
            schemas.pop(unused, None)
        app.openapi_schema = document
        return document

    app.openapi = openapi  # type: ignore[method-assign]  # FastAPI's documented way to extend it
