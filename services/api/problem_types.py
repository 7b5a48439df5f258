"""Every kind of error the API answers, once: its slug, status, title, meaning and fix.

Why a table of its own: an error body is an RFC 9457 problem (`api.problems` builds it), whose
``type`` names the kind of error by a URI a client can switch on and a person can read. That URI
is ``/docs/errors#<slug>``, a relative reference: resolved against the request's URL (RFC 9457
section 3.1.1) it is a page every API process serves (`api.problems.install_problem_page`), so it
resolves on any deployment without the service knowing where its documentation site lives. The
same table is the documentation site's errors page (docs/service/errors.md, a block generated from
`markdown_sections`), so the page, the served page and the code can never disagree.

This module holds data only (no web framework), so the docs build can import it.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Where the API serves the page of every kind; a kind's ``type`` is this plus ``#<slug>``.
PAGE_PATH = "/docs/errors"


@dataclass(frozen=True)
class ProblemType:
    """One kind of error: `slug` is its ``type``'s fragment (and the docs' anchor)."""

    slug: str
    status: int
    title: str
    meaning: str
    fix: str

    @property
    def uri(self) -> str:
        return f"{PAGE_PATH}#{self.slug}"


def _kinds(*kinds: ProblemType) -> dict[str, ProblemType]:
    return {k.slug: k for k in kinds}


KINDS: dict[str, ProblemType] = _kinds(
    ProblemType(
        "malformed-body", 400, "The request body could not be read",
        "The body is not what the route reads at all (a multipart body without its boundary's "
        "parts, a truncated form); `detail` says what the parser found.",
        "Send the body the route documents (a multipart form for uploads, JSON elsewhere).",
    ),
    ProblemType(
        "unauthorized", 401, "Missing or invalid credentials",
        "No API key, an unknown one, or (on `/metrics`) not the metrics token. The answer carries "
        "`WWW-Authenticate: Bearer`.",
        "Send the key as `X-API-Key: <key>` or `Authorization: Bearer <key>`.",
    ),
    ProblemType(
        "not-found", 404, "Not found",
        "No such path, or no such scene, job, batch, artifact or page in the caller's tenant "
        "(another tenant's ids answer this too).",
        "Check the id (ids are the service's own, e.g. `j_...`, `s_...`, `b_...`) and the key's tenant.",
    ),
    ProblemType(
        "method-not-allowed", 405, "Method not allowed",
        "The path exists but not with this method; the `Allow` header lists the methods it takes.",
        "Use one of the methods in `Allow` (see the API reference at `/docs`).",
    ),
    ProblemType(
        "request-timeout", 408, "The request body did not arrive in time",
        "The body came slower than `BFIELDS_API_BODY_TIMEOUT_S` allows (between two chunks, or in "
        "all at the minimum rate); the connection is closed.",
        "Send the body at once, at a steady rate; for large files use the direct uploads.",
    ),
    ProblemType(
        "conflict", 409, "Conflict with the current state",
        "What is asked cannot be done in the object's current state: a scene not ready, a job not "
        "succeeded yet, an upload not complete.",
        "Wait for the state `detail` names (poll the object), or change the request.",
    ),
    ProblemType(
        "busy", 409, "Another request is handling this",
        "A request with the same Idempotency-Key, or a retry of the same batch, is still running.",
        "Retry once the other request has finished; the same key then returns its result.",
    ),
    ProblemType(
        "too-large", 413, "Too large",
        "An upload, a file or an archive's expanded size is past its limit (`detail` names the "
        "setting, e.g. `BFIELDS_MAX_UPLOAD_BYTES`).",
        "Send less, or ask the operator to raise the named limit.",
    ),
    ProblemType(
        "unsupported-media-type", 415, "Unsupported media type",
        "The body's `Content-Type` is not one the route reads.",
        "Send the content type the route documents (e.g. `multipart/form-data` for POST /v1/scenes).",
    ),
    ProblemType(
        "validation", 422, "The request is invalid",
        "A field, parameter, header or file is refused; `detail` names it and the rule, and `errors` "
        "lists every refused field with its location (`loc`) for request validation.",
        "Correct the named field as `detail` says; nothing was stored.",
    ),
    ProblemType(
        "over-quota", 429, "The tenant's job quota is used up",
        "The tenant's unfinished jobs would pass its bound (`BFIELDS_MAX_WAITING_JOBS_PER_TENANT` plus "
        "`BFIELDS_MAX_ACTIVE_JOBS_PER_TENANT`); nothing was stored. `RateLimit` says how many jobs are "
        "left, `Retry-After` when to try again.",
        "Retry after `Retry-After` seconds, or submit fewer jobs at once; the quota comes back as "
        "jobs finish.",
    ),
    ProblemType(
        "too-many-requests", 429, "Too many requests of this tenant",
        "The tenant's requests on this API process came faster than `BFIELDS_API_TENANT_RATE` per "
        "second (with `BFIELDS_API_TENANT_BURST` at once), with requests already waiting their turn. "
        "`RateLimit` (policy `\"requests\"`) says what is left on every `/v1` answer.",
        "Retry after `Retry-After` seconds, or poll less often (a batch's counts, not each job).",
    ),
    ProblemType(
        "too-many-at-once", 429, "Too many requests of this tenant at once",
        "The tenant has `BFIELDS_API_TENANT_CONCURRENCY` requests in flight and "
        "`BFIELDS_API_TENANT_QUEUE` waiting on this API process.",
        "Retry after `Retry-After` seconds, or send fewer requests in parallel.",
    ),
    ProblemType(
        "internal-error", 500, "Internal error",
        "A fault of the service, not of the request (logged with its traceback on the server).",
        "Retry later; if it persists, report it with the request's time and path.",
    ),
    ProblemType(
        "not-implemented", 501, "Not available on this deployment",
        "The route needs what this deployment's storage does not offer (direct uploads need a "
        "bucket that presigns).",
        "Use the route `detail` names instead (e.g. the multipart upload of POST /v1/scenes).",
    ),
    ProblemType(
        "database-unavailable", 503, "The records database is unavailable",
        "PostgreSQL is unreachable or busy; the request was not carried out.",
        "Retry after `Retry-After` seconds; a submission with the same Idempotency-Key is safe to repeat.",
    ),
    ProblemType(
        "backend-unavailable", 503, "A backend is unavailable",
        "Redis (the queue) or the object storage did not answer in time; the request was not carried out.",
        "Retry after `Retry-After` seconds.",
    ),
    ProblemType(
        "lane-unavailable", 503, "The batch lane is unavailable",
        "The API process's bulk lane could not serve the batch in time; the batch may or may not "
        "have been stored.",
        "Retry after `Retry-After` seconds with the same Idempotency-Key: a stored batch is returned, "
        "not made twice.",
    ),
    ProblemType(
        "http-error", 0, "Other HTTP error",
        "Any other refusal of the HTTP layer (a status none of the kinds above covers); `status` "
        "says which.",
        "Read `detail`.",
    ),
)  # fmt: skip

#: The kind of an error that only has a status (a route's or the framework's HTTPException).
BY_STATUS: dict[int, str] = {
    400: "malformed-body",
    401: "unauthorized",
    404: "not-found",
    405: "method-not-allowed",
    408: "request-timeout",
    409: "conflict",
    413: "too-large",
    415: "unsupported-media-type",
    422: "validation",
    429: "too-many-requests",
    500: "internal-error",
    501: "not-implemented",
    503: "backend-unavailable",
}


def kind_of_status(status: int) -> ProblemType:
    """The kind an error of only a `status` has (``http-error`` for a status no kind covers)."""
    return KINDS[BY_STATUS.get(status, "http-error")]


def markdown_sections() -> str:
    """The errors page's generated block: one section per kind (its heading is the anchor that
    the kind's ``type`` names)."""
    out = []
    for kind in KINDS.values():
        status = "any other 4xx/5xx" if kind.status == 0 else str(kind.status)
        out += [
            f"### {kind.slug}",
            "",
            f"**{status}: {kind.title}.** {kind.meaning}",
            "",
            f"*Fix:* {kind.fix}",
            "",
        ]
    return "\n".join(out)
