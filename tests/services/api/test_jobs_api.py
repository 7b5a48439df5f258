"""Job, batch, auth and tenant-isolation behaviour of the real API (no worker needed: jobs stay
queued, and are cancelled at the end so later worker tests skip them)."""

from __future__ import annotations

import json
import re
import uuid

import httpx
import pytest

from tests.integration.fixtures.services import ApiServer

pytestmark = pytest.mark.integration

TASKS = ["red blob", "green blob"]


def _submit(client: httpx.Client, scene_id: str, **extra: object) -> httpx.Response:
    headers = extra.pop("headers", None)
    return client.post("/v1/jobs", json={"scene_id": scene_id, "tasks": TASKS, **extra}, headers=headers)  # type: ignore[arg-type]


@pytest.fixture
def queued_job(client_a: httpx.Client, stored_scene: dict):
    resp = _submit(client_a, stored_scene["id"])
    assert resp.status_code == 202, resp.text
    job_id = resp.json()["id"]
    yield job_id
    client_a.delete(f"/v1/jobs/{job_id}")


def test_auth_required_everywhere(api: ApiServer, stored_scene: dict, queued_job: str) -> None:
    routes = [
        ("GET", "/v1/scenes"),
        ("GET", f"/v1/scenes/{stored_scene['id']}"),
        ("POST", "/v1/scenes"),
        ("POST", "/v1/scenes/uploads"),
        ("DELETE", f"/v1/scenes/{stored_scene['id']}"),
        ("POST", "/v1/jobs"),
        ("GET", "/v1/jobs"),
        ("GET", f"/v1/jobs/{queued_job}"),
        ("GET", f"/v1/jobs/{queued_job}/result"),
        ("GET", f"/v1/jobs/{queued_job}/result.zip"),
        ("DELETE", f"/v1/jobs/{queued_job}"),
        ("POST", "/v1/batches"),
        ("GET", "/v1/batches/b_0000000000000000000000"),
    ]
    for headers in ({}, {"X-API-Key": "wrong"}, {"Authorization": "Bearer wrong"}):
        for method, path in routes:
            resp = httpx.request(method, api.base_url + path, headers=headers, timeout=10)
            assert resp.status_code == 401, (method, path, headers, resp.text)
            assert "API key" in resp.json()["detail"]
    key = api.keys["tenant-a"]
    ok = httpx.get(f"{api.base_url}/v1/jobs/{queued_job}", headers={"Authorization": f"Bearer {key}"})
    assert ok.status_code == 200
    assert httpx.get(f"{api.base_url}/healthz").status_code == 200  # probes need no key


def test_job_lifecycle_without_worker(client_a: httpx.Client, queued_job: str, stored_scene: dict) -> None:
    for route in ("result", "result.zip"):  # nothing to download before the job has succeeded
        resp = client_a.get(f"/v1/jobs/{queued_job}/{route}")
        assert resp.status_code == 409 and "is queued, not succeeded" in resp.json()["detail"], route
    job = client_a.get(f"/v1/jobs/{queued_job}").json()
    assert job["state"] == "queued" and job["scene_id"] == stored_scene["id"] and job["tasks"] == TASKS
    assert client_a.get(f"/v1/jobs/{queued_job}/result").status_code == 409
    listed = client_a.get("/v1/jobs", params={"scene_id": stored_scene["id"], "state": "queued"}).json()
    assert queued_job in [j["id"] for j in listed["items"]]
    cancelled = client_a.delete(f"/v1/jobs/{queued_job}")
    assert cancelled.status_code == 202 and cancelled.json()["state"] == "cancelled"
    assert client_a.get(f"/v1/jobs/{queued_job}").json()["state"] == "cancelled"
    queued_now = client_a.get("/v1/jobs", params={"scene_id": stored_scene["id"], "state": "queued"}).json()
    assert queued_job not in [j["id"] for j in queued_now["items"]]


def test_job_validation(client_a: httpx.Client, stored_scene: dict) -> None:
    sid = stored_scene["id"]
    bad = [
        ({"scene_id": sid, "tasks": []}, "tasks"),
        ({"scene_id": sid, "tasks": ["a", "a"]}, "duplicate"),
        ({"scene_id": sid, "tasks": ["a"], "parameters": {"top_kk": 3}}, "top_kk"),
        ({"scene_id": sid, "tasks": ["a"], "parameters": {"top_k": 0}}, "top_k"),
        ({"scene_id": sid, "tasks": ["a"], "model_profile": "huge"}, "huge"),
        ({"scene_id": sid, "tasks": [f"task {i}" for i in range(21)]}, "at most 20"),
        ({"scene_id": sid, "tasks": ["get the " + "very " * 12 + "red cube"]}, "longer than 60"),
    ]
    for body, fragment in bad:
        resp = client_a.post("/v1/jobs", json=body)
        assert resp.status_code == 422, body
        assert fragment in resp.text, (body, resp.text)
    missing = client_a.post("/v1/jobs", json={"scene_id": "s_0000000000000000000000", "tasks": ["a"]})
    assert missing.status_code == 404


def test_idempotency_key_returns_the_same_job(client_a: httpx.Client, stored_scene: dict) -> None:
    key = {"Idempotency-Key": f"retry-{uuid.uuid4()}"}
    first = _submit(client_a, stored_scene["id"], headers=key)
    second = _submit(client_a, stored_scene["id"], headers=key)
    other = _submit(client_a, stored_scene["id"], headers={"Idempotency-Key": f"other-{uuid.uuid4()}"})
    try:
        assert first.status_code == 202 and first.json()["created"] is True
        assert second.status_code == 200 and second.json()["created"] is False
        assert second.json()["id"] == first.json()["id"]
        assert other.json()["id"] != first.json()["id"]
    finally:
        for resp in (first, other):
            client_a.delete(f"/v1/jobs/{resp.json()['id']}")


def test_batch_status_aggregates(client_a: httpx.Client, stored_scene: dict) -> None:
    body = {"scene_ids": [stored_scene["id"]], "task_lists": [["red blob"], ["green blob", "blue blob"]]}
    resp = client_a.post("/v1/batches", json=body)
    assert resp.status_code == 202, resp.text
    batch = resp.json()
    assert len(batch["jobs"]) == 2 and batch["counts"] == {"queued": 2} and not batch["finished"]
    assert [j["tasks"] for j in batch["jobs"]] == body["task_lists"]
    for job in batch["jobs"]:
        client_a.delete(f"/v1/jobs/{job['id']}")
    done = client_a.get(f"/v1/batches/{batch['id']}").json()
    assert done["counts"] == {"cancelled": 2} and done["finished"] and done["progress"] == 100.0
    bad = client_a.post("/v1/batches", json={"items": [{"scene_id": stored_scene["id"], "tasks": ["a"]},
                                                       {"scene_id": "s_0000000000000000000000", "tasks": ["b"]}]})  # fmt: skip
    assert bad.status_code == 404  # validated before anything is queued


def _sse(client: httpx.Client, path: str) -> list[tuple[str, dict]]:
    """The events of a server-sent-event stream that ends by itself (a finished batch's)."""
    events: list[tuple[str, dict]] = []
    with client.stream("GET", path, timeout=30.0) as resp:
        assert resp.status_code == 200
        name = ""
        for line in resp.iter_lines():
            if line.startswith("event: "):
                name = line[7:]
            elif line.startswith("data: "):
                events.append((name, json.loads(line[6:])))
    return events


def test_batch_status_is_the_aggregate_and_lists_jobs_only_when_asked_within_the_bound(
    client_a: httpx.Client, stored_scene: dict
) -> None:
    """Issue 41: one tenant polling a 20,000-job batch (listed by default) slowed every tenant.
    The default answer is counts and progress; jobs=true is answered up to
    BFIELDS_BATCH_JOBS_INLINE_MAX (50 in the service tests) and refused past it with a 422 that
    names the field and the paged route; the paged route reads every job of any batch."""
    small = client_a.post(
        "/v1/batches", json={"scene_ids": [stored_scene["id"]], "task_lists": [["a"], ["b"]]}
    )
    bound = 50
    big = client_a.post("/v1/batches", json={"scene_ids": [stored_scene["id"]],
                                              "task_lists": [[f"t {i}"] for i in range(bound + 1)]})  # fmt: skip
    assert small.status_code == 202 and big.status_code == 202, (small.text, big.text)
    small_id, big_id = small.json()["id"], big.json()["id"]
    try:
        plain = client_a.get(f"/v1/batches/{small_id}").json()
        assert plain["jobs"] == [] and plain["total"] == 2 and sum(plain["counts"].values()) == 2
        listed = client_a.get(f"/v1/batches/{small_id}", params={"jobs": "true"}).json()
        assert [j["tasks"] for j in listed["jobs"]] == [["a"], ["b"]]

        aggregate = client_a.get(f"/v1/batches/{big_id}")
        assert aggregate.status_code == 200 and aggregate.json()["jobs"] == [], aggregate.text
        assert aggregate.json()["total"] == bound + 1
        refused = client_a.get(f"/v1/batches/{big_id}", params={"jobs": "true"})
        assert refused.status_code == 422, refused.text
        detail = refused.json()["detail"]
        assert detail.startswith("query.jobs: ") and f"/v1/batches/{big_id}/jobs" in detail, detail
        assert str(bound) in detail and "BFIELDS_BATCH_JOBS_INLINE_MAX" in detail, detail
        assert refused.json()["errors"][0]["loc"] == ["query", "jobs"]
        paged, cursor = [], None
        while True:
            page = client_a.get(f"/v1/batches/{big_id}/jobs",
                                params={"limit": 20, **({"cursor": cursor} if cursor else {})}).json()  # fmt: skip
            paged += page["items"]
            if not (cursor := page["next_cursor"]):
                break
        assert [j["tasks"] for j in paged] == [[f"t {i}"] for i in range(bound + 1)]
    finally:
        for batch_id in (small_id, big_id):
            assert client_a.post(f"/v1/batches/{batch_id}/cancel").status_code == 202

    # a large batch's event stream sends counts only (no per-job read each round); a small one every job
    big_events = _sse(client_a, f"/v1/batches/{big_id}/events")
    assert [name for name, _ in big_events] == ["counts", "end"], big_events
    assert big_events[0][1]["counts"] == {"cancelled": bound + 1} and big_events[0][1]["finished"]
    small_events = _sse(client_a, f"/v1/batches/{small_id}/events")
    assert [name for name, _ in small_events] == ["job", "job", "counts", "end"], small_events


def test_tenant_isolation_on_every_route(
    client_a: httpx.Client, client_b: httpx.Client, stored_scene: dict, queued_job: str
) -> None:
    sid = stored_scene["id"]
    batch = client_a.post("/v1/batches", json={"items": [{"scene_id": sid, "tasks": ["x"]}]}).json()
    try:
        for method, path in [
            ("GET", f"/v1/scenes/{sid}"),
            ("DELETE", f"/v1/scenes/{sid}"),
            ("POST", f"/v1/scenes/{sid}/complete"),
            ("GET", f"/v1/jobs/{queued_job}"),
            ("GET", f"/v1/jobs/{queued_job}/result"),
            ("GET", f"/v1/jobs/{queued_job}/artifacts/result/summary.json"),
            ("GET", f"/v1/jobs/{queued_job}/result.zip"),
            ("DELETE", f"/v1/jobs/{queued_job}"),
            ("GET", f"/v1/batches/{batch['id']}"),
        ]:
            resp = client_b.request(method, path)
            assert resp.status_code == 404, (method, path, resp.text)
        assert client_b.post("/v1/jobs", json={"scene_id": sid, "tasks": ["x"]}).status_code == 404
        assert (
            client_b.post("/v1/batches", json={"scene_ids": [sid], "task_lists": [["x"]]}).status_code == 404
        )
        assert sid not in [s["id"] for s in client_b.get("/v1/scenes").json()["items"]]
        assert queued_job not in [j["id"] for j in client_b.get("/v1/jobs").json()["items"]]
        # tenant-b's failed attempts changed nothing of tenant-a's
        assert client_a.get(f"/v1/scenes/{sid}").json() == stored_scene
        assert client_a.get(f"/v1/jobs/{queued_job}").json()["state"] == "queued"
    finally:
        client_a.delete(f"/v1/jobs/{batch['jobs'][0]['id']}")


def test_scene_with_active_job_cannot_be_deleted(
    client_a: httpx.Client, stored_scene: dict, queued_job: str
) -> None:
    resp = client_a.delete(f"/v1/scenes/{stored_scene['id']}")
    assert resp.status_code == 409 and queued_job in resp.text


def test_openapi_health_and_metrics(api: ApiServer) -> None:
    spec = httpx.get(f"{api.base_url}/openapi.json").json()
    for path in ["/v1/scenes", "/v1/scenes/uploads", "/v1/scenes/{scene_id}/complete", "/v1/jobs",
                 "/v1/jobs/{job_id}/result", "/v1/batches/{batch_id}", "/readyz", "/metrics"]:  # fmt: skip
        assert path in spec["paths"], path
    assert "multipart/form-data" in spec["paths"]["/v1/scenes"]["post"]["requestBody"]["content"]
    assert spec["components"]["schemas"]["JobRequest"]["examples"]
    ready = httpx.get(f"{api.base_url}/readyz")
    assert ready.status_code == 200
    assert ready.json()["checks"] == {"postgresql": "ok", "redis": "ok", "storage": "ok"}
    metrics = api.metrics()
    assert 'bfields_queue_depth{queue="gpu"}' in metrics and "bfields_jobs_active" in metrics


def test_the_docs_page_names_no_other_host_and_its_assets_are_served(api: ApiServer) -> None:
    """/docs works offline (issue 41): FastAPI's page loaded Swagger UI from a CDN and its favicon
    from fastapi.tiangolo.com; the API serves them itself now."""
    page = httpx.get(f"{api.base_url}/docs")
    assert page.status_code == 200 and "text/html" in page.headers["content-type"]
    assert re.findall(r"(?:https?:)?//[A-Za-z0-9.-]+", page.text) == [], "the page names another host"
    assets = re.findall(r"""(?:src|href)=['"]([^'"]+)['"]|url: ['"]([^'"]+)['"]""", page.text)
    urls = sorted({a or b for a, b in assets})
    assert "/openapi.json" in urls and any(u.endswith("swagger-ui-bundle.js") for u in urls), urls
    for url in urls:
        resp = httpx.get(f"{api.base_url}{url}")
        assert resp.status_code == 200 and resp.content, url
    assert "SwaggerUIBundle" in httpx.get(f"{api.base_url}/docs/assets/swagger-ui-bundle.js").text
    assert httpx.get(f"{api.base_url}/redoc").status_code == 404  # CDN-only; /openapi.json instead


def test_cli_batch_submits_scenes_x_task_lists(
    api: ApiServer,
    scene_dir,
    stored_scene: dict,
    tmp_path,
    capsys: pytest.CaptureFixture[str],  # noqa: ANN001
) -> None:
    from bayesian_fields_service.client import batch

    (tmp_path / "tasks.txt").write_text("red blob\nblue blob\n")
    manifest = tmp_path / "batch.yaml"
    manifest.write_text(
        f"scenes: [{scene_dir}, {stored_scene['id']}]\n"
        "task_lists: [[green blob], tasks.txt]\n"
        "parameters: {max_frames: 2}\n"
    )
    assert batch(manifest, server=api.base_url, api_key=api.keys["tenant-a"], wait=False) == 0
    batch_id = capsys.readouterr().out.strip().splitlines()[-1]
    with api.client("tenant-a") as client:
        state = client.get(f"/v1/batches/{batch_id}", params={"jobs": "true"}).json()
        try:
            assert len(state["jobs"]) == 4  # 2 scenes x 2 task lists
            assert sorted(map(tuple, (j["tasks"] for j in state["jobs"]))) == sorted(
                [("green blob",), ("red blob", "blue blob")] * 2
            )
            assert len({j["scene_id"] for j in state["jobs"]}) == 2 and stored_scene["id"] in {
                j["scene_id"] for j in state["jobs"]
            }
            job = client.get(f"/v1/jobs/{state['jobs'][0]['id']}").json()
            assert job["parameters"] == {"max_frames": 2} and job["batch_id"] == batch_id
        finally:
            for j in state["jobs"]:
                client.delete(f"/v1/jobs/{j['id']}")
    bad = tmp_path / "bad.yaml"
    bad.write_text("scenes: []\n")
    from bayesian_fields_service.client.commands import _run

    assert _run(batch, manifest=bad, server=api.base_url, api_key=api.keys["tenant-a"], wait=False) == 2


def test_an_idempotency_key_sent_again_with_another_body_is_a_422_naming_it(
    client_a: httpx.Client, stored_scene: dict
) -> None:
    """The IETF Idempotency-Key draft: a key stands for one request. The same body again is the
    same job (200); another task list, scene or parameters under that key is refused, and the
    first job is untouched. Batches and batch items alike."""
    key = f"reuse-{uuid.uuid4()}"
    first = _submit(client_a, stored_scene["id"], headers={"Idempotency-Key": key})
    try:
        assert first.status_code == 202, first.text
        again = client_a.post("/v1/jobs", json={"scene_id": stored_scene["id"], "tasks": ["another task"]},
                              headers={"Idempotency-Key": key})  # fmt: skip
        assert again.status_code == 422 and key in again.text, again.text
        params = client_a.post(
            "/v1/jobs",
            json={"scene_id": stored_scene["id"], "tasks": TASKS, "parameters": {"max_frames": 3}},
            headers={"Idempotency-Key": key},
        )
        assert params.status_code == 422 and key in params.text, params.text
        assert client_a.get(f"/v1/jobs/{first.json()['id']}").json()["tasks"] == TASKS

        batch_key = f"batch-{uuid.uuid4()}"
        body = {"scene_ids": [stored_scene["id"]], "task_lists": [["red blob"]]}
        made = client_a.post("/v1/batches", json=body, headers={"Idempotency-Key": batch_key})
        assert made.status_code == 202, made.text
        same = client_a.post("/v1/batches", json=body, headers={"Idempotency-Key": batch_key})
        assert same.status_code == 200 and same.json()["id"] == made.json()["id"]
        other = {"scene_ids": [stored_scene["id"]], "task_lists": [["green blob"]]}
        refused = client_a.post("/v1/batches", json=other, headers={"Idempotency-Key": batch_key})
        assert refused.status_code == 422 and batch_key in refused.text, refused.text
        client_a.post(f"/v1/batches/{made.json()['id']}/cancel")

        item = {
            "scene_id": stored_scene["id"],
            "tasks": ["blue blob"],
            "idempotency_key": f"item-{uuid.uuid4()}",
        }
        kept = client_a.post("/v1/batches", json={"items": [item]})
        assert kept.status_code == 202, kept.text
        reused = client_a.post("/v1/batches", json={"items": [{**item, "tasks": ["green blob"]}]})
        assert reused.status_code == 422 and item["idempotency_key"] in reused.text, reused.text
        client_a.post(f"/v1/batches/{kept.json()['id']}/cancel")
    finally:
        client_a.delete(f"/v1/jobs/{first.json()['id']}")
