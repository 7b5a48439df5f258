"""What every request meets before a route: UTF-8 only, and one error body for every refusal.

Why a middleware: FastAPI decodes JSON with Python's `json`, which turns ``"\\ud800"`` into a
str holding a lone surrogate. Pydantic accepts it, it is stored, and every later response that
contains it fails to encode (500). Refusing it once, here, covers every string of every JSON body
(values and keys, tasks, names, parameters), every query parameter (percent-encoded bytes that
are not UTF-8) and the headers the API reads, with a 422 naming the field. Multipart form fields
are decoded by `bayesian_fields_service.api.multipart` with replacement, so they never carry surrogates.

The handlers give every 4xx/5xx the problem body of `api.problems` (RFC 9457, one kind per
refusal: `api.problem_types`): ``detail`` is always a string; request validation adds ``errors``
(one entry per field). The domain's refusals (`jobs.refusals`, the
scenes' exceptions) are answered here, so a route only calls the domain and shapes the answer.
Backend outages (Redis, the broker, the bucket, the records database: `records_outage`) become
503 with ``Retry-After`` and no internal detail (that goes to the log).
"""

from __future__ import annotations

import json
import logging
import re
from typing import Any
from urllib.parse import unquote_to_bytes

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from bayesian_fields_service.api.bulk_lane import LaneUnavailable
from bayesian_fields_service.api.problem_types import kind_of_status
from bayesian_fields_service.api.problems import RETRY_STATUSES, problem_response
from bayesian_fields_service.api.ratelimit import quota_headers
from bayesian_fields_service.api.records_outage import OUTAGES, cause
from bayesian_fields_service.jobs.refusals import Busy, Conflict, Invalid, Missing, OverQuota, Refused
from bayesian_fields_service.live.broker import BROKER_ERRORS
from bayesian_fields_service.sanitize.text import redact_locations, scrub_text
from bayesian_fields_service.scenes.refusals import (
    NoDirectUploads,
    SceneConflict,
    SceneGone,
    SceneRefused,
    UploadTooLarge,
)

#: The problem type (`api.problem_types`: status, title) of each kind of the jobs domain's refusals.
REFUSAL_KIND: dict[type[Refused], str] = {
    Invalid: "validation",
    Missing: "not-found",
    Conflict: "conflict",
    Busy: "busy",
    OverQuota: "over-quota",
}

#: The problem type of each kind of the scenes domain's refusals (a subclass takes its base's).
SCENE_REFUSAL_KIND: dict[type[SceneRefused], str] = {
    SceneGone: "not-found",
    SceneConflict: "conflict",
    UploadTooLarge: "too-large",
    NoDirectUploads: "not-implemented",
}

log = logging.getLogger(__name__)

#: Headers whose values the API uses as data (they must be printable ASCII).
CHECKED_HEADERS = {
    "idempotency-key": "Idempotency-Key",
    "x-api-key": "X-API-Key",
    "authorization": "Authorization",
}
#: JSON bodies larger than this are left to FastAPI unparsed here (the routes' bodies are small).
MAX_CHECKED_BODY = 16 * 1024 * 1024

_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89a-fA-F]")
"""The only way a body that decodes as UTF-8 can carry a lone surrogate: a JSON escape of one. A
body without any is not parsed a second time (a fleet-sized batch's parse held the event loop)."""


def _loc(path: list[str | int]) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def first_unencodable(value: Any, path: list[str | int]) -> list[str | int] | None:
    """The location of the first string (or mapping key) in `value` that is not valid UTF-8."""
    if isinstance(value, str):
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            return path
        return None
    if isinstance(value, dict):
        for key, item in value.items():
            if first_unencodable(key, [*path, "<key>"]) is not None:
                return [*path, scrub_text(key)]
            if (found := first_unencodable(item, [*path, key])) is not None:
                return found
    if isinstance(value, list):
        for i, item in enumerate(value):
            if (found := first_unencodable(item, [*path, i])) is not None:
                return found
    return None


def _not_utf8(loc: list[str | int], what: str, path: str) -> JSONResponse:
    where = _loc(loc)
    msg = f"{what} (a lone UTF-16 surrogate, or bytes that are not UTF-8); send valid UTF-8 text"
    return problem_response(
        "validation", f"{where}: {msg}", path, errors=[{"loc": loc, "msg": msg, "type": "utf8"}]
    )


def _check_query(raw: bytes, path: str) -> JSONResponse | None:
    """Every query parameter's name and value are UTF-8 without a NUL (which no text column of
    PostgreSQL holds, and no parameter of the API needs)."""
    for pair in raw.split(b"&"):
        name, _, value = pair.partition(b"=")
        for part, is_name in ((name, True), (value, False)):
            try:
                decoded = unquote_to_bytes(part.replace(b"+", b" ")).decode("utf-8")
            except UnicodeDecodeError:
                label = unquote_to_bytes(name).decode("utf-8", "replace")
                return _not_utf8(
                    ["query", label], "parameter name is not UTF-8" if is_name else "is not UTF-8", path
                )
            if "\x00" in decoded:
                label = scrub_text(unquote_to_bytes(name).decode("utf-8", "replace"))
                msg = "must not contain a NUL character"
                return problem_response(
                    "validation", f"query.{label}: {msg}", path,
                    errors=[{"loc": ["query", label], "msg": msg, "type": "nul"}],
                )  # fmt: skip
    return None


def _check_headers(headers: list[tuple[bytes, bytes]], path: str) -> JSONResponse | None:
    for name, value in headers:
        if name.lower().decode("latin-1") in CHECKED_HEADERS and not all(0x20 <= b < 0x7F for b in value):
            label = CHECKED_HEADERS[name.lower().decode("latin-1")]
            msg = "must be printable ASCII"
            return problem_response(
                "validation", f"header.{label}: {msg}", path,
                errors=[{"loc": ["header", label], "msg": msg, "type": "ascii"}],
            )  # fmt: skip
    return None


class Utf8Guard:
    """Pure ASGI middleware: refuse non-UTF-8 text in JSON bodies (FastAPI also parses a body
    without a content type as JSON, so those are checked too), query strings and the headers the
    API reads; the body is buffered once and replayed to the app unchanged."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path = scope["path"]
        refusal = _check_query(scope.get("query_string", b""), path) or _check_headers(
            scope.get("headers", []), path
        )
        content_type = dict(scope.get("headers", [])).get(b"content-type", b"").lower()
        if (
            refusal is None
            and scope["method"] in ("POST", "PUT", "PATCH")
            and (b"json" in content_type or not content_type)
        ):
            body, more = b"", True
            while more and len(body) <= MAX_CHECKED_BODY:
                message = await receive()
                if message["type"] == "http.disconnect":
                    return
                body += message.get("body", b"")
                more = message.get("more_body", False)
            refusal = self._check_body(body, path) if not more else None
            receive = _replay(body, more, receive)
        if refusal is not None:
            await refusal(scope, receive, send)
            return
        await self.app(scope, receive, send)

    @staticmethod
    def _check_body(body: bytes, path: str) -> JSONResponse | None:
        try:
            text = body.decode("utf-8")
        except UnicodeDecodeError as exc:
            return _not_utf8(["body"], f"byte {exc.start} is not UTF-8", path)
        if _SURROGATE_ESCAPE.search(text) is None:
            return None  # valid UTF-8 text holds no surrogate but through a \\uD800-\\uDFFF escape
        try:
            data = json.loads(text)
        except (json.JSONDecodeError, RecursionError):
            return None  # FastAPI answers malformed JSON with its own 422
        where = first_unencodable(data, ["body"])
        return _not_utf8(where, "is not valid UTF-8", path) if where is not None else None


def _replay(body: bytes, more: bool, receive: Receive) -> Receive:
    sent = False

    async def replay() -> Message:
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": more}
        return await receive()

    return replay


def _validation_errors(exc: RequestValidationError) -> list[dict[str, Any]]:
    return [
        {"loc": [scrub_text(p) if isinstance(p, str) else p for p in e.get("loc", ())],
         "msg": scrub_text(str(e.get("msg", ""))), "type": str(e.get("type", ""))}
        for e in exc.errors()
    ]  # fmt: skip


def install_handlers(app: FastAPI, retry_after_s: int) -> None:
    """The error handlers that give every refusal its problem body (`api.problems`)."""
    from bayesian_fields_core.errors import InputError

    try:
        from bayesian_fields_service.storage.s3_store import StorageError
    except ImportError:  # pragma: no cover - local-store deployments without boto3
        StorageError = OSError  # type: ignore[misc,assignment]  # noqa: N806
    retry = {"Retry-After": str(retry_after_s)}

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = _validation_errors(exc)
        detail = "; ".join(f"{_loc(e['loc'])}: {e['msg']}" for e in errors[:5]) or "invalid request"
        return problem_response("validation", detail, request.url.path, errors=errors)

    @app.exception_handler(InputError)
    async def _input_error(request: Request, exc: InputError) -> JSONResponse:
        return problem_response("validation", redact_locations(str(exc)), request.url.path)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> Response:
        """Every route's own error (and the framework's 404 / 405), with the same redaction as
        input errors: a message built from a bucket key or a server path by any route never
        reaches the client with it."""
        if exc.status_code in (204, 304):
            return Response(status_code=exc.status_code, headers=exc.headers)
        headers = dict(exc.headers) if exc.headers else {}
        if exc.status_code in RETRY_STATUSES:
            headers = {**retry, **headers}
        return problem_response(
            kind_of_status(exc.status_code), redact_locations(str(exc.detail)), request.url.path,
            status=exc.status_code, headers=headers or None,
        )  # fmt: skip

    @app.exception_handler(Refused)
    async def _refused(request: Request, exc: Refused) -> JSONResponse:
        """The jobs domain's refusals (`jobs.refusals`): each kind its problem type; a refusal
        past the tenant's quota says the quota's state (`api.ratelimit`)."""
        headers = None
        if isinstance(exc, OverQuota):
            headers = {"Retry-After": str(exc.retry_after_s)}
            if exc.quota is not None:
                headers |= quota_headers(exc.quota, reset_s=exc.retry_after_s)
        return problem_response(REFUSAL_KIND[type(exc)], redact_locations(str(exc)), request.url.path,
                                headers=headers)  # fmt: skip

    @app.exception_handler(SceneRefused)
    async def _scene_refused(request: Request, exc: SceneRefused) -> JSONResponse:
        """The scenes domain's refusals (`scenes.refusals`): each kind its problem type."""
        kind = next(k for k in type(exc).__mro__ if k in SCENE_REFUSAL_KIND)
        return problem_response(SCENE_REFUSAL_KIND[kind], redact_locations(str(exc)), request.url.path)

    async def _outage(request: Request, exc: Exception) -> JSONResponse:
        backend = "object storage" if isinstance(exc, StorageError) else "the queue (Redis)"
        log.warning("%s %s: %s unavailable: %s: %s", request.method, request.url.path, backend,
                    type(exc).__name__, exc)  # fmt: skip
        return problem_response(
            "backend-unavailable",
            f"{backend} is unavailable; the request was not carried out, retry in {retry_after_s} s",
            request.url.path,
            headers=retry,
        )

    @app.exception_handler(LaneUnavailable)
    async def _lane(request: Request, exc: LaneUnavailable) -> JSONResponse:
        log.warning("%s %s: %s", request.method, request.url.path, exc)
        return problem_response("lane-unavailable", str(exc), request.url.path, headers=retry)

    async def _records_outage(request: Request, exc: Exception) -> JSONResponse:
        log.warning("%s %s: records database: %s: %s", request.method, request.url.path,
                    type(exc).__name__, str(exc).splitlines()[0] if str(exc) else "")  # fmt: skip
        return problem_response(
            "database-unavailable",
            f"{cause(exc)}; retry in {retry_after_s} s (a submission with the same Idempotency-Key)",
            request.url.path,
            headers=retry,
        )

    async def _internal(request: Request, exc: Exception) -> JSONResponse:
        """A fault of the service: the problem body instead of Starlette's plain text (the
        traceback still goes to the log, where Starlette re-raises it)."""
        return problem_response(
            "internal-error", "internal error; the request may not have been carried out", request.url.path
        )

    for kind in (*BROKER_ERRORS, StorageError):
        app.add_exception_handler(kind, _outage)
    for kind in OUTAGES:  # the records database (`records_outage`)
        app.add_exception_handler(kind, _records_outage)
    app.add_exception_handler(Exception, _internal)
