"""The two readings of a request's API key agree (services/security/auth.py): FastAPI's security
schemes, which the routes' authentication uses, and `key_in_headers`, which the tenant fairness
middleware uses before any route runs and whose tenant the routes then take as resolved. A
disagreement would let the middleware count a request against one tenant while the route served
another, so every way of sending (or mis-sending) a key is read both ways here."""

from __future__ import annotations

import pytest
from fastapi import Depends, FastAPI, Request
from fastapi.testclient import TestClient

from bayesian_fields_service.security.auth import key_in_headers, presented_key

CASES = [
    {},
    {"X-API-Key": "k1"},
    {"X-API-Key": ""},
    {"Authorization": "Bearer k2"},
    {"Authorization": "bearer k2"},
    {"Authorization": "BEARER k2"},
    {"Authorization": "Basic k2"},
    {"Authorization": "Bearer"},
    {"Authorization": "Bearer "},
    {"Authorization": "k2"},
    {"X-API-Key": "k1", "Authorization": "Bearer k2"},
    {"X-API-Key": "", "Authorization": "Bearer k2"},
]


@pytest.fixture(scope="module")
def client() -> TestClient:
    app = FastAPI()

    @app.get("/key")
    def key(request: Request, presented: str | None = Depends(presented_key)) -> dict[str, str | None]:
        headers = request.headers
        return {
            "route": presented,
            "middleware": key_in_headers(headers.get("x-api-key"), headers.get("authorization")),
        }

    return TestClient(app)


@pytest.mark.parametrize("headers", CASES, ids=[repr(c) for c in CASES])
def test_the_middleware_and_the_routes_read_the_same_key(client: TestClient, headers: dict[str, str]) -> None:
    answer = client.get("/key", headers=headers)
    assert answer.status_code == 200, answer.text
    read = answer.json()
    assert read["route"] == read["middleware"]
