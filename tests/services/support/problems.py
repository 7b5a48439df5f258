"""What every error answer of the API must be: an RFC 9457 problem whose `type` is a documented
kind (docs/service/errors.md, `api.problem_types`). Shared by the tests that meet an error answer
(validation, auth, quotas, outages, the body deadline, the tenant gate)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import httpx

ERRORS_PAGE = Path(__file__).resolve().parents[3] / "docs" / "service" / "errors.md"
MEDIA_TYPE = "application/problem+json"
MEMBERS = ("type", "title", "status", "detail", "instance")


def documented_kinds(page: Path = ERRORS_PAGE) -> set[str]:
    """The anchors of the errors page's kind sections (its ``### <kind>`` headings, whose ids
    MkDocs makes from the text)."""
    return set(re.findall(r"^### ([a-z0-9-]+)$", page.read_text(encoding="utf-8"), re.M))


def check_problem(
    status: int, content_type: str, body: dict[str, Any], expected_status: int, kind: str, instance: str
) -> dict[str, Any]:
    """The checks on one answer's parts (for answers read off a raw socket too)."""
    assert status == expected_status, (status, body)
    assert content_type.split(";")[0].strip() == MEDIA_TYPE, content_type
    assert all(m in body for m in MEMBERS), body
    assert body["status"] == expected_status and body["instance"] == instance, body
    assert isinstance(body["detail"], str) and body["detail"] and isinstance(body["title"], str), body
    assert body["type"] == f"/docs/errors#{kind}", body
    assert kind in documented_kinds(), f"{kind} has no section in {ERRORS_PAGE}"
    return body


def assert_problem(
    resp: httpx.Response, status: int, kind: str, instance: str | None = None
) -> dict[str, Any]:
    """`resp` is a problem of `kind` at `status` for the request's own path; returns its body."""
    return check_problem(
        resp.status_code, resp.headers.get("content-type", ""), resp.json(), status, kind,
        instance if instance is not None else resp.request.url.path,
    )  # fmt: skip


def raw_problem(answer: bytes) -> tuple[int, str, dict[str, Any]]:
    """(status, content type, body) of an HTTP/1.1 answer read off a socket (Content-Length body)."""
    head, _, body = answer.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    headers = {k.strip().lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:])}
    return int(lines[0].split(" ", 2)[1]), headers.get("content-type", ""), json.loads(body)
