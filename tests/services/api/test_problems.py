"""Errors as RFC 9457 problems and quotas in RateLimit headers (issue 44, items 4 and 5).

Real HTTP against real API processes: a sample of every kind of error comes back as
``application/problem+json`` with the five members, a ``type`` that names a section of
docs/service/errors.md and resolves (against the request's URL) to a section of the API's own
``/docs/errors`` page, and the ``detail`` / ``errors`` that clients read before. The OpenAPI
document says the same. The job quota's ``RateLimit`` falls as submissions use it, and its 429
says so. The 503 (records outage), 408 (body deadline) and the tenant gate's 429 are checked where
their stacks already are: test_records_outage.py, test_body_deadline.py, test_tenant_fairness.py.
"""

from __future__ import annotations

import ast
import json
import re
import secrets
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urljoin

import httpx
import pytest
from starlette.datastructures import MutableHeaders

from bayesian_fields_service.api.problem_types import BY_STATUS, KINDS
from bayesian_fields_service.api.ratelimit import add_policies
from bayesian_fields_service.client.api import BFieldsClient, ClientError
from tests.integration.fixtures.postgres import create_database, drop_database
from tests.integration.fixtures.services import ApiServer
from tests.services.conftest import MAX_UPLOAD, scene_form
from tests.services.support.problems import MEDIA_TYPE, MEMBERS, assert_problem, documented_kinds

REPO = Path(__file__).resolve().parents[3]
UNKNOWN_JOB = "j_" + "0" * 22


def _resolves(resp: httpx.Response, body: dict) -> None:
    """The problem's `type`, resolved against the request's URL, is a page with that section."""
    url = urljoin(str(resp.request.url), body["type"])
    page = httpx.get(url.split("#")[0])
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html"), url
    assert f'id="{url.split("#")[1]}"' in page.text, url


@pytest.mark.integration
def test_a_sample_of_every_kind_of_error_is_a_documented_problem(
    api: ApiServer, client_a: httpx.Client, stored_scene: dict
) -> None:
    answers = []
    # 422, request validation: `errors` and `detail` as before
    invalid = client_a.post("/v1/jobs", json={"scene_id": stored_scene["id"]})
    body = assert_problem(invalid, 422, "validation")
    assert body["errors"] == [{"loc": ["body", "tasks"], "msg": "Field required", "type": "missing"}]
    assert "body.tasks" in body["detail"]
    answers.append((invalid, body))
    # 422 from the UTF-8 guard, a middleware that answers before any route
    nul = client_a.get("/v1/jobs", params={"scene_id": "a\x00"})
    body = assert_problem(nul, 422, "validation")
    assert body["errors"][0]["loc"] == ["query", "scene_id"] and "NUL" in body["detail"]
    answers.append((nul, body))
    # 404: an unknown id, an unknown path
    for path in (f"/v1/jobs/{UNKNOWN_JOB}", "/v1/no-such-thing"):
        missing = client_a.get(path)
        answers.append((missing, assert_problem(missing, 404, "not-found")))
    assert UNKNOWN_JOB in answers[-2][1]["detail"]
    # 401: no key
    anonymous = httpx.get(f"{api.base_url}/v1/jobs")
    answers.append((anonymous, assert_problem(anonymous, 401, "unauthorized")))
    assert anonymous.headers["WWW-Authenticate"] == "Bearer" and "X-API-Key" in answers[-1][1]["detail"]
    # 405: the framework's own
    wrong_method = client_a.put("/v1/jobs")
    answers.append((wrong_method, assert_problem(wrong_method, 405, "method-not-allowed")))
    assert "POST" in wrong_method.headers["Allow"]  # (Starlette names the first matching route's)
    # 413: a declared upload past the limit
    too_big = client_a.post(
        "/v1/scenes/uploads", json={"files": [{"field": "images", "name": "a.zip", "size": MAX_UPLOAD + 1}]}
    )
    answers.append((too_big, assert_problem(too_big, 413, "too-large")))
    assert str(MAX_UPLOAD) in answers[-1][1]["detail"]
    # 409: the result of a job that has not finished (cancelled after); a submission, and a batch
    # (served by the API's bulk lane child here), carry the quota's headers
    job = client_a.post("/v1/jobs", json={"scene_id": stored_scene["id"], "tasks": ["a problem"]})
    batch = client_a.post("/v1/batches", json={"scene_ids": [stored_scene["id"]], "task_lists": [["b"]]})
    try:
        assert job.status_code == 202 and batch.status_code == 202, (job.text, batch.text)
        for submitted in (job, batch):
            assert submitted.headers["RateLimit"].startswith('"jobs";r='), submitted.headers
            assert submitted.headers["RateLimit-Policy"].startswith('"jobs";q='), submitted.headers
        early = client_a.get(f"/v1/jobs/{job.json()['id']}/result")
        answers.append((early, assert_problem(early, 409, "conflict")))
    finally:
        client_a.delete(f"/v1/jobs/{job.json()['id']}")
        client_a.post(f"/v1/batches/{batch.json()['id']}/cancel")
    for resp, body in answers:
        _resolves(resp, body)
    # the CLI's client prints the same one line as before (it reads `detail`)
    with BFieldsClient(api.base_url, api.keys["tenant-a"]) as bf, pytest.raises(ClientError) as refused:
        bf.job(UNKNOWN_JOB)
    assert str(refused.value) == f"GET /v1/jobs/{UNKNOWN_JOB}: HTTP 404: job {UNKNOWN_JOB!r} not found"
    # a success is not a problem
    assert client_a.get("/v1/jobs", params={"limit": 1}).headers["content-type"] == "application/json"


@pytest.mark.integration
def test_the_openapi_document_declares_problems_on_every_error(api: ApiServer) -> None:
    spec = httpx.get(f"{api.base_url}/openapi.json").json()
    problem = spec["components"]["schemas"]["Problem"]
    assert set(MEMBERS) <= set(problem["required"]) and "errors" in problem["properties"]
    assert "HTTPValidationError" not in spec["components"]["schemas"]
    errors = 0
    for path, methods in spec["paths"].items():
        for method, op in methods.items():
            for code, response in op["responses"].items():
                if int(code) < 400 or (path, code) == ("/readyz", "503"):  # readiness: its report
                    continue
                errors += 1
                assert response["content"] == {MEDIA_TYPE: {"schema": {"$ref": "#/components/schemas/Problem"}}}, (
                    path, method, code,
                )  # fmt: skip
                if code in ("429", "503"):
                    assert "Retry-After" in response["headers"], (path, method, code)
    assert errors > 50, errors
    for path in ("/v1/jobs", "/v1/batches"):
        responses = spec["paths"][path]["post"]["responses"]
        for code in ("202", "429"):
            assert {"RateLimit-Policy", "RateLimit"} <= set(responses[code]["headers"]), (path, code)
        assert "application/json" in responses["202"]["content"], path  # the answer's model is kept


def _code_kinds() -> set[str]:
    """The kinds the API's code names: every `problem_response("<kind>", ...)` call and the
    values of the refusal tables (`api.edge`), read from the sources."""
    found: set[str] = set()
    for source in (REPO / "services" / "api").rglob("*.py"):
        tree = ast.parse(source.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "problem_response":
                first = node.args[0] if node.args else None
                if isinstance(first, ast.Constant) and isinstance(first.value, str):
                    found.add(first.value)
            if isinstance(node, ast.AnnAssign) and getattr(node.target, "id", "").endswith("REFUSAL_KIND"):
                assert isinstance(node.value, ast.Dict)
                found |= {v.value for v in node.value.values if isinstance(v, ast.Constant)}
    return found


def test_every_documented_kind_is_used_and_every_kind_in_code_is_documented() -> None:
    documented = documented_kinds()
    assert documented == set(KINDS), documented ^ set(KINDS)
    named = _code_kinds()
    assert named <= set(KINDS), named - set(KINDS)
    # what only a status names (a route's HTTPException, the framework's 404/405) maps to a kind;
    # `http-error` is the kind of any other status
    used = named | set(BY_STATUS.values()) | {"http-error"}
    assert used == set(KINDS), set(KINDS) - used
    assert {"validation", "over-quota", "too-many-requests", "too-many-at-once", "request-timeout", "database-unavailable",
            "backend-unavailable", "lane-unavailable", "busy", "internal-error"} <= named  # fmt: skip
    for kind in KINDS.values():
        assert kind.status == 0 or BY_STATUS.get(kind.status) in KINDS, kind


# ---- RateLimit headers on what the job quota bounds -----------------------------------------------

_ITEM = re.compile(r'^"(?P<name>[a-z-]+)"(?P<params>(;[a-z]+=("[a-z-]+"|\d+))*)$')


def _field(value: str) -> tuple[str, dict[str, str]]:
    """A one-item Structured Field list (RFC 9651) of the RateLimit draft: (name, parameters)."""
    match = _ITEM.match(value)
    assert match is not None, value
    params = dict(p.split("=", 1) for p in match["params"].split(";")[1:])
    return match["name"], params


def _remaining(resp: httpx.Response, quota: int) -> int:
    assert _field(resp.headers["RateLimit-Policy"]) == ("jobs", {"q": str(quota)}), resp.headers
    name, params = _field(resp.headers["RateLimit"])
    assert name == "jobs", resp.headers
    return int(params["r"])


def test_an_answer_under_two_policies_lists_both() -> None:
    """A submission's answer has the job quota's fields; the request rate (`api.tenant_rate`) adds
    its policy to the same Lists instead of being dropped or replacing them."""
    headers = MutableHeaders(raw=[(b"ratelimit-policy", b'"jobs";q=3'), (b"ratelimit", b'"jobs";r=2')])
    add_policies(headers, {"RateLimit-Policy": '"requests";q=50;w=1', "RateLimit": '"requests";r=19;t=1',
                           "Retry-After": "1"})  # fmt: skip
    assert headers["RateLimit-Policy"] == '"jobs";q=3, "requests";q=50;w=1'
    assert headers["RateLimit"] == '"jobs";r=2, "requests";r=19;t=1' and headers["Retry-After"] == "1"
    plain = MutableHeaders(raw=[(b"retry-after", b"5")])
    add_policies(plain, {"RateLimit": '"requests";r=0;t=2', "Retry-After": "2"})
    assert plain["RateLimit"] == '"requests";r=0;t=2' and plain["Retry-After"] == "5"


QUOTA = 3  # one dispatched + two waiting


@pytest.fixture
def quota_api(tmp_path: Path, svc_env: dict[str, str]) -> Iterator[tuple[ApiServer, str]]:
    """An API at a job quota of 3 for a fresh tenant, with a records database of its own and no
    control process (nothing is dispatched: every job stays unfinished)."""
    tenant = "tenant-r" + secrets.token_hex(3)
    keys = {tenant: "key-r-" + secrets.token_urlsafe(12)}
    env = {
        **svc_env,
        "BFIELDS_MAX_ACTIVE_JOBS_PER_TENANT": "1",
        "BFIELDS_MAX_WAITING_JOBS_PER_TENANT": str(QUOTA - 1),
        "BFIELDS_API_KEYS": json.dumps({keys[tenant]: tenant}),
        "BFIELDS_API_BULK_LANE": "false",
        "BFIELDS_DATABASE_URL": create_database(),
    }
    server = ApiServer(env=env, log_dir=tmp_path / "api", keys=keys, control=False).start()
    yield server, tenant
    server.stop()
    drop_database(env["BFIELDS_DATABASE_URL"])


@pytest.mark.integration
def test_the_job_quota_falls_in_ratelimit_headers_and_its_429_says_when(
    quota_api: tuple[ApiServer, str], scene_dir: Path
) -> None:
    api, tenant = quota_api
    with api.client(tenant) as client:
        scene = client.post("/v1/scenes", files=scene_form(scene_dir), data={"name": "quota"})
        assert scene.status_code == 201, scene.text
        sid = scene.json()["id"]

        first = client.post("/v1/jobs", json={"scene_id": sid, "tasks": ["one"]})
        assert first.status_code == 202 and _remaining(first, QUOTA) == 2, first.headers
        batch = client.post("/v1/batches", json={"scene_ids": [sid], "task_lists": [["two"]]})
        assert batch.status_code == 202 and _remaining(batch, QUOTA) == 1, batch.headers
        keyed = client.post(
            "/v1/jobs", json={"scene_id": sid, "tasks": ["three"]}, headers={"Idempotency-Key": "k3"}
        )
        assert keyed.status_code == 202 and _remaining(keyed, QUOTA) == 0, keyed.headers
        # the earlier job of the key: nothing stored, no quota used, no RateLimit fields
        again = client.post(
            "/v1/jobs", json={"scene_id": sid, "tasks": ["three"]}, headers={"Idempotency-Key": "k3"}
        )
        assert again.status_code == 200 and "RateLimit" not in again.headers, again.headers

        for path, body in (("/v1/jobs", {"scene_id": sid, "tasks": ["four"]}),
                           ("/v1/batches", {"scene_ids": [sid], "task_lists": [["four"], ["five"]]})):  # fmt: skip
            refused = client.post(path, json=body)
            problem = assert_problem(refused, 429, "over-quota")
            assert f"at most {QUOTA}" in problem["detail"]
            assert refused.headers["Retry-After"] == "5"
            assert _remaining(refused, QUOTA) == 0
            assert _field(refused.headers["RateLimit"])[1]["t"] == refused.headers["Retry-After"]

        # a cancelled job gives its unit back: the next submission is admitted with none left
        assert client.delete(f"/v1/jobs/{first.json()['id']}").status_code == 202
        after = client.post("/v1/jobs", json={"scene_id": sid, "tasks": ["four"]})
        assert after.status_code == 202 and _remaining(after, QUOTA) == 0, after.text
