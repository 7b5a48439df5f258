"""Hostile input at the API's edge (issue 12, items 1, 4, 8): non-UTF-8 text, control characters,
non-finite or unbounded parameters, parameters the scene cannot satisfy, old stored records that
hold such text, and the one error body (`Problem`) every refusal carries. Real HTTP, real stack."""

from __future__ import annotations

import httpx
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_service.jobs.model import JobRecord, JobState
from bayesian_fields_service.records.database import engine
from bayesian_fields_service.records.tables import jobs

pytestmark = pytest.mark.integration


def _post_raw(client: httpx.Client, path: str, text: str, **kw: object) -> httpx.Response:
    """POST a JSON document written by hand (so it can hold escapes json.dumps would not write)."""
    headers = {"Content-Type": "application/json", **kw.pop("headers", {})}  # type: ignore[dict-item]
    return client.post(path, content=text.encode(), headers=headers, **kw)  # type: ignore[arg-type]


def _assert_problem(resp: httpx.Response, status: int, *fragments: str) -> dict:
    assert resp.status_code == status, resp.text
    body = resp.json()
    assert isinstance(body["detail"], str), body
    for fragment in fragments:
        assert fragment in body["detail"], (fragment, body)
    return body


def test_lone_surrogates_refused_in_every_field(client_a: httpx.Client, stored_scene: dict) -> None:
    sid = stored_scene["id"]
    cases = [
        ("/v1/jobs", f'{{"scene_id": "{sid}", "tasks": ["get \\ud800 mug"]}}', "body.tasks[0]"),
        (
            "/v1/jobs",
            f'{{"scene_id": "{sid}", "tasks": ["a"], "model_profile": "\\udfff"}}',
            "body.model_profile",
        ),
        (
            "/v1/jobs",
            f'{{"scene_id": "{sid}", "tasks": ["a"], "parameters": {{"\\ud800": 1}}}}',
            "body.parameters",
        ),
        ("/v1/jobs", f'{{"scene_id": "{sid}\\ud800", "tasks": ["a"]}}', "body.scene_id"),
        (
            "/v1/batches",
            f'{{"scene_ids": ["{sid}"], "task_lists": [["ok", "x\\udc00"]]}}',
            "body.task_lists[0][1]",
        ),
        ("/v1/scenes/uploads", '{"name": "kitchen \\ud83d", "files": []}', "body.name"),
    ]
    for path, text, where in cases:
        body = _assert_problem(_post_raw(client_a, path, text), 422, where, "UTF-8")
        assert body["errors"][0]["loc"][0] == "body"
    # bytes that are not UTF-8 at all: a 422 naming the body, not FastAPI's undocumented 400
    raw = client_a.post("/v1/jobs", content=b'{"scene_id": "\xff", "tasks": ["a"]}',
                        headers={"Content-Type": "application/json"})  # fmt: skip
    _assert_problem(raw, 422, "body", "UTF-8")
    # FastAPI parses a body without a content type as JSON too: checked the same way
    bare = client_a.post("/v1/jobs", content=f'{{"scene_id": "{sid}", "tasks": ["\\ud800"]}}'.encode())
    assert "content-type" not in bare.request.headers
    _assert_problem(bare, 422, "body.tasks[0]", "UTF-8")
    # percent-encoded bytes that are not UTF-8 in a query string, and a non-ASCII Idempotency-Key
    _assert_problem(client_a.get("/v1/jobs?scene_id=%ED%A0%80"), 422, "query.scene_id")
    idem = client_a.post(
        "/v1/jobs",
        json={"scene_id": sid, "tasks": ["a"]},
        headers={"Idempotency-Key": "k\xe9y".encode("latin-1")},
    )
    _assert_problem(idem, 422, "Idempotency-Key")
    # nothing was stored: the tenant's jobs still list and none carries the probes' tasks
    # by scene: the made-up id sorts oldest, behind every other job tenant-a has in the session
    listed = client_a.get("/v1/jobs", params={"limit": 500, "scene_id": stored_scene["id"]})
    assert listed.status_code == 200
    assert not [j for j in listed.json()["items"] if "ok" in j["tasks"] or "get \ufffd mug" in j["tasks"]]


@pytest.mark.parametrize(
    ("task", "what"),
    [
        ("get\u202e gum", "U+202E"),
        ("a\u2066b", "U+2066"),
        ("ring \x07 bell", "U+0007"),
        ("nul\x00", "U+0000"),
    ],
)
def test_control_and_bidi_characters_in_tasks_refused(
    client_a: httpx.Client, stored_scene: dict, task: str, what: str
) -> None:
    resp = client_a.post("/v1/jobs", json={"scene_id": stored_scene["id"], "tasks": ["fine", task]})
    _assert_problem(resp, 422, "task #2", what)


def test_whitespace_in_tasks_is_normalised(client_a: httpx.Client, stored_scene: dict) -> None:
    resp = client_a.post("/v1/jobs", json={"scene_id": stored_scene["id"], "tasks": ["red\t\n  blob"]})
    assert resp.status_code == 202, resp.text
    job_id = resp.json()["id"]
    try:
        assert client_a.get(f"/v1/jobs/{job_id}").json()["tasks"] == ["red blob"]
    finally:
        client_a.delete(f"/v1/jobs/{job_id}")


def test_stored_records_with_bad_text_stay_readable_and_deletable(
    client_a: httpx.Client, stored_scene: dict, svc_env: dict[str, str]
) -> None:
    """A stored record whose error message names a worker temp path and an internal bucket key
    (written before messages were redacted on write): served redacted, listed, cancelled. (Lone
    surrogates cannot reach a row: the edge refuses them and PostgreSQL's UTF-8 would too.)"""
    record = JobRecord(id="j_00000000000100000000aa", tenant="tenant-a", scene_id=stored_scene["id"],
                       tasks=["get mug"], state=JobState.queued)  # fmt: skip
    error = (
        "fuse: internal error: FileNotFoundError: [Errno 2] No such file or directory: "
        "'/tmp/bfields-stage-8f3a/scenes/input/depth/d_0001.npy' (tenants/tenant-a/scenes/x/input/y.png)"
    )
    row = {name: value for name, value in record.model_dump(mode="json").items() if name in jobs.c}
    with engine(svc_env["BFIELDS_DATABASE_URL"]).begin() as conn:  # as an older API stored it
        conn.execute(
            jobs.insert().values(**{**row, "error": error, "created_at": record.created_at,
                                    "updated_at": record.updated_at})
        )  # fmt: skip
    got = client_a.get(f"/v1/jobs/{record.id}")
    assert got.status_code == 200, got.text
    job = got.json()
    assert "/tmp" not in job["error"] and "tenants/" not in job["error"] and "d_0001.npy" in job["error"]
    # every page: the made-up id sorts oldest, behind every other job tenant-a has in the session
    listed_ids: list[str] = []
    params: dict[str, str | int] = {"limit": 500}
    while True:
        listed = client_a.get("/v1/jobs", params=params)
        assert listed.status_code == 200, listed.text
        listed_ids += [j["id"] for j in listed.json()["items"]]
        if not (cursor := listed.json()["next_cursor"]):
            break
        params["cursor"] = cursor
    assert record.id in listed_ids
    cancelled = client_a.delete(f"/v1/jobs/{record.id}")
    assert cancelled.status_code == 202 and cancelled.json()["state"] == "cancelled", cancelled.text


def test_parameters_must_be_finite_bounded_and_fit_the_scene(
    client_a: httpx.Client, stored_scene: dict
) -> None:
    sid = stored_scene["id"]
    raw = [
        ('{"prior": NaN}', "parameters.prior", "finite"),
        ('{"depth_tolerance": Infinity}', "parameters.depth_tolerance", "finite"),
        ('{"mu0": -Infinity}', "parameters.mu0", "finite"),
        ('{"top_k": 1000000000000000000}', "parameters.top_k", "1000"),
        ('{"knn_k": 100000}', "parameters.knn_k", "1000"),
        ('{"frame_stride": 0}', "parameters.frame_stride", "1"),
        ('{"device": "cuda; rm -rf /"}', "parameters.device", "pattern"),
        ('{"depth_source": "input"}', "parameters.depth_source", "0 of 4"),
    ]
    for params, where, limit in raw:
        resp = _post_raw(
            client_a, "/v1/jobs", f'{{"scene_id": "{sid}", "tasks": ["a"], "parameters": {params}}}'
        )
        _assert_problem(resp, 422, where, limit)
    batch = _post_raw(client_a, "/v1/batches", f'{{"scene_ids": ["{sid}"], "task_lists": [["a"]], '
                                               '"parameters": {"s": NaN}}')  # fmt: skip
    _assert_problem(batch, 422, "parameters.s", "finite")


def test_cli_params_get_the_same_bounds() -> None:
    from bayesian_fields_core.cli.job_options import build_params

    for item, fragment in [("top_k=1000000000000000000", "top_k"), ("s=.nan", "s"), ("prior=.inf", "prior")]:
        with pytest.raises(InputError) as err:
            build_params(None, [item])
        assert fragment in str(err.value)
    assert build_params(None, ["top_k=7"]).top_k == 7


def test_validation_errors_are_problems_and_documented(
    api, client_a: httpx.Client, stored_scene: dict
) -> None:  # noqa: ANN001
    body = _assert_problem(
        client_a.post("/v1/jobs", json={"scene_id": stored_scene["id"]}), 422, "body.tasks"
    )
    assert body["errors"] == [{"loc": ["body", "tasks"], "msg": "Field required", "type": "missing"}]
    _assert_problem(client_a.get("/v1/jobs", params={"limit": 0}), 422, "query.limit")
    spec = httpx.get(f"{api.base_url}/openapi.json").json()
    problem = spec["components"]["schemas"]["Problem"]
    assert problem["properties"]["detail"]["type"] == "string" and "errors" in problem["properties"]
    submit = spec["paths"]["/v1/jobs"]["post"]["responses"]
    assert {"200", "202", "400", "401", "404", "409", "422", "429", "503"} <= set(submit)
    for path, methods in spec["paths"].items():
        if path.startswith("/v1/"):
            for op in methods.values():
                assert "503" in op["responses"], path


def test_ids_and_cursors_with_a_nul_or_stray_characters_are_refused_not_looked_up(
    client_a: httpx.Client, stored_scene: dict
) -> None:
    """Ids and cursors are the service's own: a NUL (which PostgreSQL refuses in text: it was a
    500) or any other character outside an id is a 404 / 422 before any lookup (schemathesis)."""
    for scene_id in ("s_\u0000" + "0" * 21, "*\u00c9\u001f+,\u00f0c\u0000", stored_scene["id"] + "\u0000"):
        resp = client_a.post("/v1/jobs", json={"scene_id": scene_id, "tasks": ["a"]})
        assert resp.status_code == 404 and "not found" in resp.json()["detail"], resp.text
        batch = client_a.post("/v1/batches", json={"scene_ids": [scene_id], "task_lists": [["a"]]})
        assert batch.status_code == 404, batch.text
    listed = client_a.get("/v1/scenes", params={"cursor": "\u0000"})
    assert listed.status_code == 422 and "cursor" in listed.text, listed.text
    assert client_a.get("/v1/scenes", params={"cursor": stored_scene["id"]}).status_code == 200


def test_a_scene_name_with_control_characters_is_refused(client_a: httpx.Client) -> None:
    """A NUL in a scene's name reached PostgreSQL's text column (500): refused with 422 first."""
    spec = {"name": "kitchen\u0000", "files": [{"field": "images", "name": "images.zip", "size": 10}]}
    resp = client_a.post("/v1/scenes/uploads", json=spec)
    assert resp.status_code == 422 and "name" in resp.json()["detail"], resp.text
