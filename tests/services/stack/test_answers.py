"""Fleet answers on the real stack (issue 42): a batch of real jobs over the test scene, run by real
Celery workers, whose answers become rows with their success; then the batch's answer table
(pages, filters, CSV and JSON Lines parsed back), the fleet search, another tenant's view, the
hostile query values, the backfill command run twice, and a scene's delete removing its answers."""

from __future__ import annotations

import csv
import io
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from sqlalchemy import text

from bayesian_fields_service.records.database import engine
from tests.integration.fixtures.services import ApiServer, WorkerPool
from tests.services.conftest import scene_form

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(600)]

PARAMS = {"max_frames": 4}
TASK_LISTS = [["red blob", "green blob"], ["red blob", "purple elephant"], ["green blob"]]


def _wait_batch(client: httpx.Client, batch_id: str, timeout_s: float = 400) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        got = client.get(f"/v1/batches/{batch_id}").json()
        if got["finished"]:
            return got
        time.sleep(0.5)
    raise AssertionError(f"batch {batch_id} did not finish: {got}")


@pytest.fixture(scope="module")
def fleet(api: ApiServer, workers: WorkerPool, scene_dir: Path) -> dict:
    """Two scenes of tenant-a, a batch of each scene x `TASK_LISTS` (6 jobs), all succeeded."""
    with api.client("tenant-a") as client:
        scenes = []
        for name in ("room-1", "room-2"):
            resp = client.post("/v1/scenes", files=scene_form(scene_dir), data={"name": name})
            assert resp.status_code == 201, resp.text
            scenes.append(resp.json()["id"])
        resp = client.post(
            "/v1/batches", json={"scene_ids": scenes, "task_lists": TASK_LISTS, "parameters": PARAMS}
        )
        assert resp.status_code == 202, resp.text
        batch = resp.json()
        done = _wait_batch(client, batch["id"])
        assert done["counts"] == {"succeeded": len(scenes) * len(TASK_LISTS)}, done
        jobs = client.get(f"/v1/batches/{batch['id']}/jobs").json()["items"]
        summaries = {j["id"]: client.get(f"/v1/jobs/{j['id']}/result").json()["summary"] for j in jobs}
    return {"batch": batch["id"], "scenes": scenes, "jobs": jobs, "summaries": summaries}


def _all_pages(client: httpx.Client, path: str, **params: object) -> list[dict]:
    rows, cursor = [], None
    while True:
        page = client.get(path, params={**params, **({"cursor": cursor} if cursor else {})})
        assert page.status_code == 200, page.text
        rows += page.json()["items"]
        if not (cursor := page.json()["next_cursor"]):
            return rows


def test_every_job_answer_is_a_row_equal_to_its_summary(fleet: dict, client_a: httpx.Client) -> None:
    rows = _all_pages(client_a, f"/v1/batches/{fleet['batch']}/answers", limit=500)
    for job in fleet["jobs"]:
        summary = fleet["summaries"][job["id"]]
        mine = [r for r in rows if r["job_id"] == job["id"]]
        assert sorted({r["task"] for r in mine}) == sorted(job["tasks"])
        for entry in summary["selections"]:
            task_rows = sorted((r for r in mine if r["task"] == entry["task"]), key=lambda r: r["rank"])
            if not entry["objects"]:
                assert [(r["rank"], r["found"]) for r in task_rows] == [(0, False)]
                assert task_rows[0]["not_found_reason"]
                continue
            assert [r["object_id"] for r in task_rows] == [o["object_id"] for o in entry["objects"]]
            best, first = task_rows[0], entry["objects"][0]
            assert best["rank"] == 1 and best["found"]
            assert best["probability"] == pytest.approx(first["probability"])
            assert best["content_key"] == first["key"]
            assert best["best_view_score"] == pytest.approx(first["best_view_score"])
            assert best["num_gaussians"] == first["num_gaussians"]
            framed = first.get("world_frame") or first.get("capture_frame") or first
            assert [best["centre_x"], best["centre_y"], best["centre_z"]] == pytest.approx(
                framed["box"]["center"]
            )
            assert [best["centroid_x"], best["centroid_y"], best["centroid_z"]] == pytest.approx(
                framed["centroid"]
            )
            assert sum(best["rotation"], []) == pytest.approx(sum(framed["box"]["rotation"], []))
            index = summary["tasks"].index(entry["task"])
            assert best["preview"] == "result/" + summary["previews"]["tasks"][index]["file"]
            image = (
                httpx.get(best["preview_url"])
                if best["preview_url"].startswith("http")
                else client_a.get(best["preview_url"])
            )
            assert image.status_code == 200 and image.content.startswith(b"\x89PNG")


def test_pages_are_stable_and_filters_apply(fleet: dict, client_a: httpx.Client) -> None:
    path = f"/v1/batches/{fleet['batch']}/answers"
    whole = _all_pages(client_a, path, limit=500)
    paged = _all_pages(client_a, path, limit=3)
    assert _without_links(paged) == _without_links(whole) and len(whole) > 3
    keys = [(r["job_id"], r["task_index"], r["rank"]) for r in whole]
    assert len(set(keys)) == len(keys)

    red = _all_pages(client_a, path, task="RED", limit=500)  # a unique part, any case
    assert red and {r["task"] for r in red} == {"red blob"}
    best = _all_pages(client_a, path, task="red blob", max_rank=1, found="true")
    assert {r["rank"] for r in best} == {1} and len(best) == 4  # 2 scenes x 2 jobs asked it
    sure = _all_pages(client_a, path, min_probability=0.5)
    assert all(r["probability"] >= 0.5 for r in sure)
    assert len(sure) == sum(1 for r in whole if r["probability"] is not None and r["probability"] >= 0.5)
    one = _all_pages(client_a, path, scene="room-2")
    assert (
        one
        and {r["scene_id"] for r in one} == {fleet["scenes"][1]}
        and {r["scene_name"] for r in one} == {"room-2"}
    )
    missing = _all_pages(client_a, path, found="false")
    assert all(not r["found"] and r["rank"] == 0 for r in missing)
    assert len(missing) == sum(1 for r in whole if not r["found"])

    ambiguous = client_a.get(path, params={"task": "blob"})
    assert ambiguous.status_code == 422 and "several tasks" in ambiguous.text and "task" in ambiguous.text


def test_the_whole_table_streams_as_csv_and_json_lines(fleet: dict, client_a: httpx.Client) -> None:
    path = f"/v1/batches/{fleet['batch']}/answers"
    whole = _all_pages(client_a, path, limit=500)
    as_csv = client_a.get(path, params={"format": "csv"})
    assert as_csv.status_code == 200 and as_csv.headers["content-type"].startswith("text/csv")
    table = list(csv.DictReader(io.StringIO(as_csv.text)))
    assert [(r["job_id"], int(r["task_index"]), int(r["rank"])) for r in table] == [
        (r["job_id"], r["task_index"], r["rank"]) for r in whole
    ]
    found = [r for r in table if r["found"] == "True"]
    assert [float(r["probability"]) for r in found] == pytest.approx(
        [r["probability"] for r in whole if r["found"]]
    )

    lines = client_a.get(path, headers={"Accept": "application/x-ndjson"})
    assert lines.headers["content-type"].startswith("application/x-ndjson")
    parsed = [json.loads(line) for line in lines.text.splitlines()]
    assert _without_links(whole) == parsed
    filtered = client_a.get(path, params={"format": "jsonl", "task": "green", "max_rank": 1})
    assert {json.loads(x)["task"] for x in filtered.text.splitlines()} == {"green blob"}


def test_the_fleet_search_ranks_each_scenes_latest_answer(fleet: dict, client_a: httpx.Client) -> None:
    # tenant-a's jobs of other modules in this session may have asked "red blob" too: the exact
    # counts are read within this fleet's batch, the whole fleet's search must contain them
    anywhere = client_a.get("/v1/answers", params={"task": "red blob"})
    assert anywhere.status_code == 200, anywhere.text
    assert anywhere.json()["asked"] >= 2
    got = client_a.get("/v1/answers", params={"task": "red blob", "batch": fleet["batch"]})
    assert got.status_code == 200, got.text
    body = got.json()
    assert body["task"] == "red blob" and body["asked"] == 2
    assert body["found"] + body["not_found"] == 2 and len(body["items"]) == body["found"]
    mine = {r["job_id"] for r in body["items"]}
    assert mine <= {r["job_id"] for r in anywhere.json()["items"]}
    latest = {}
    for job in fleet["jobs"]:  # each scene's latest succeeded job that asked it
        if "red blob" in job["tasks"]:
            if job["scene_id"] not in latest or job["finished_at"] > latest[job["scene_id"]]["finished_at"]:
                latest[job["scene_id"]] = job
    assert {r["job_id"] for r in body["items"]} <= {j["id"] for j in latest.values()}
    probs = [r["probability"] for r in body["items"]]
    assert probs == sorted(probs, reverse=True) and all(r["rank"] == 1 for r in body["items"])
    every = _all_pages(
        client_a, "/v1/answers", task="red blob", all_ranks="true", limit=1, batch=fleet["batch"]
    )
    assert len(every) >= len(body["items"]) and {r["job_id"] for r in every} <= {
        j["id"] for j in latest.values()
    }
    scoped = client_a.get("/v1/answers", params={"task": "red", "batch": fleet["batch"]}).json()
    assert scoped["asked"] == 2 and scoped["task"] == "red blob"
    nobody = client_a.get("/v1/answers", params={"task": "a unicorn"}).json()
    assert (nobody["asked"], nobody["items"]) == (0, [])


def test_another_tenant_sees_nothing(fleet: dict, client_b: httpx.Client) -> None:
    assert client_b.get(f"/v1/batches/{fleet['batch']}/answers").status_code == 404
    assert client_b.get(f"/v1/batches/{fleet['batch']}/answers", params={"format": "csv"}).status_code == 404
    theirs = client_b.get("/v1/answers", params={"task": "red blob"}).json()
    assert (theirs["asked"], theirs["items"]) == (0, [])
    assert (
        client_b.get("/v1/answers", params={"task": "red blob", "batch": fleet["batch"]}).status_code == 404
    )


@pytest.mark.parametrize(
    ("params", "field"),
    [
        ({"min_probability": "nan"}, "min_probability"),
        ({"min_probability": "1.5"}, "min_probability"),
        ({"min_probability": "-inf"}, "min_probability"),
        ({"max_rank": "0"}, "max_rank"),
        ({"max_rank": "99999999999999999999"}, "max_rank"),
        ({"found": "maybe"}, "found"),
        ({"task": "red\x00blob"}, "task"),
        ({"task": "  "}, "task"),
        ({"task": "x" * 1001}, "task"),
        ({"scene": "a\nb"}, "scene"),
        ({"cursor": "1.2"}, "cursor"),
        ({"cursor": "99999999999.0.0"}, "cursor"),
        ({"cursor": "'; DROP TABLE answers; --"}, "cursor"),
        ({"format": "xml"}, "format"),
        ({"limit": "0"}, "limit"),
        ({"limit": "501"}, "limit"),
    ],
)
def test_hostile_query_values_are_422_naming_the_field(
    fleet: dict, client_a: httpx.Client, params: dict, field: str
) -> None:
    for path in (f"/v1/batches/{fleet['batch']}/answers", "/v1/answers"):
        if path == "/v1/answers" and field in ("max_rank", "found", "scene", "format"):
            continue
        query = params if path != "/v1/answers" or "task" in params else {**params, "task": "red blob"}
        got = client_a.get(path, params=query)
        assert got.status_code == 422, (path, params, got.text)
        assert field in got.text, got.text
    assert client_a.get("/v1/answers").status_code == 422
    assert client_a.get("/v1/answers", params={"task": "red", "batch": "b_nope"}).status_code == 422
    assert client_a.get("/v1/answers", params={"task": "red", "cursor": "j_00.1"}).status_code == 422


def test_the_cli_prints_the_batch_and_the_fleet(
    fleet: dict, api: ApiServer, client_a: httpx.Client, tmp_path: Path
) -> None:
    """`bfields answers` as a user runs it (a subprocess, piped): CSV to a file equal to the API's
    rows; the table piped, whole; --all ranks the fleet; a bad request is one line and exit 2."""
    env = {
        **os.environ,
        "BFIELDS_SERVER": api.base_url,
        "BFIELDS_API_KEY": api.keys["tenant-a"],
        "COLUMNS": "60",
    }
    cli = [sys.executable, "-m", "bayesian_fields_core.cli", "answers"]
    out = tmp_path / "a.csv"
    done = subprocess.run([*cli, fleet["batch"], "--task", "red", "--format", "csv", "--out", str(out)],
                          env=env, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    table = list(csv.DictReader(out.open()))
    rows = _all_pages(client_a, f"/v1/batches/{fleet['batch']}/answers", task="red blob")
    assert [(r["job_id"], int(r["rank"])) for r in table] == [(r["job_id"], r["rank"]) for r in rows]
    shown = subprocess.run([*cli, fleet["batch"]], env=env, capture_output=True, text=True, timeout=120)
    assert shown.returncode == 0 and all(r["job_id"] in shown.stdout for r in rows)  # never cut at 60 columns
    best = subprocess.run([*cli, "--all", "--task", "red blob", "--format", "json"], env=env, capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    listed = json.loads(best.stdout)
    assert [r["job_id"] for r in listed] == [
        r["job_id"] for r in client_a.get("/v1/answers", params={"task": "red blob"}).json()["items"]
    ]
    bad = subprocess.run([*cli, "--all"], env=env, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--all needs --task" in bad.stderr and "Traceback" not in bad.stderr


def _without_links(rows: list[dict]) -> list[dict]:
    """Rows without `preview_url`: a presigned link differs from one request to the next."""
    return [{k: v for k, v in r.items() if k != "preview_url"} for r in rows]


def test_the_backfill_indexes_jobs_without_answers_once(
    fleet: dict, api: ApiServer, client_a: httpx.Client
) -> None:
    path = f"/v1/batches/{fleet['batch']}/answers"
    before = _all_pages(client_a, path, limit=500)
    url = api.env["BFIELDS_DATABASE_URL"]
    victims = [j["id"] for j in fleet["jobs"][:2]]
    with engine(url).begin() as conn:  # as a job that succeeded before revision 0009
        conn.execute(text("DELETE FROM answers WHERE job_id = ANY(:ids)"), {"ids": victims})
    assert len(_all_pages(client_a, path, limit=500)) < len(before)
    env = {**os.environ, **api.env}
    command = [str(Path(sys.executable).parent / "bfields-service"), "index-answers"]
    first = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
    assert first.returncode == 0, first.stderr
    assert "indexed 2 of 2 succeeded jobs without answers" in first.stdout.splitlines()[-1]
    assert _without_links(_all_pages(client_a, path, limit=500)) == _without_links(before)
    again = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
    assert again.stdout.splitlines()[-1].startswith("indexed 0 of 0 ")
    assert _without_links(_all_pages(client_a, path, limit=500)) == _without_links(before)


def test_the_batch_page_shows_each_tasks_answers_ranked(fleet: dict, api: ApiServer, client_a: httpx.Client,
                                                        browser) -> None:  # noqa: ANN001  # fmt: skip
    """In chromium: per task, the scenes where it was found (best first) with a preview linking to
    the job page, and the count of scenes that answered "not found"."""
    rows = _all_pages(client_a, f"/v1/batches/{fleet['batch']}/answers", max_rank=1, limit=500)
    page = browser.new_context(viewport={"width": 1200, "height": 900}).new_page()
    page.goto(f"{api.base_url}/ui/")
    page.fill("#api-key", api.keys["tenant-a"])
    page.click("#login")
    page.wait_for_selector("#app:not(.hidden)")
    page.goto(f"{api.base_url}/ui/batches/{fleet['batch']}")
    page.wait_for_selector("body[data-answers]")
    assert page.evaluate("document.body.dataset.answers") == str(len(rows))
    for task in ("red blob", "green blob", "purple elephant"):
        mine = [r for r in rows if r["task"] == task]
        best: dict[str, dict] = {}
        for r in mine:
            if r["found"] and (
                r["scene_id"] not in best or r["probability"] > best[r["scene_id"]]["probability"]
            ):
                best[r["scene_id"]] = r
        ranked = sorted(best.values(), key=lambda r: -r["probability"])
        missing = len({r["scene_id"] for r in mine}) - len(ranked)
        table = page.locator(f"table.answers[data-task='{task}']")
        caption = table.locator("caption").text_content()
        assert caption == f"{task}: found in {len(ranked)} scene(s), not found in {missing}"
        shown = table.locator("tbody tr")
        assert shown.count() == len(ranked)
        for i, r in enumerate(ranked):
            tr = shown.nth(i)
            assert tr.get_attribute("data-job") == r["job_id"]
            assert tr.locator("td").nth(2).text_content() == f"{r['probability']:.3f}"
            assert tr.locator("td a img").count() == 1
            assert tr.locator("td a").last.get_attribute("href") == f"/ui/jobs/{r['job_id']}"
    page.wait_for_function(
        "[...document.querySelectorAll('table.answers img.thumb')].every(i => i.complete && i.naturalWidth > 0)"
    )
    assert page.locator("table.answers img.thumb").count() > 0
    if os.environ.get("BFIELDS_UI_SCREENSHOTS") == "1":
        page.screenshot(
            path=str(Path(__file__).resolve().parents[3] / "docs" / "ui-batch-answers.png"), full_page=True
        )


def test_deleting_a_scene_removes_its_answers(fleet: dict, api: ApiServer, client_a: httpx.Client) -> None:
    """Last in the module: it deletes room-2."""
    path = f"/v1/batches/{fleet['batch']}/answers"
    gone = fleet["scenes"][1]
    assert _all_pages(client_a, path, scene=gone)
    assert client_a.delete(f"/v1/scenes/{gone}").status_code == 204
    rows = _all_pages(client_a, path, limit=500)
    assert rows and gone not in {r["scene_id"] for r in rows}
    assert (
        client_a.get("/v1/answers", params={"task": "red blob", "batch": fleet["batch"]}).json()["asked"] == 1
    )
    with engine(api.env["BFIELDS_DATABASE_URL"]).begin() as conn:  # a job's row deleted takes its answers
        job = rows[0]["job_id"]
        conn.execute(text("DELETE FROM batch_jobs WHERE job_id = :j"), {"j": job})
        conn.execute(text("DELETE FROM jobs WHERE id = :j"), {"j": job})
        left = conn.execute(text("SELECT count(*) FROM answers WHERE job_id = :j"), {"j": job}).scalar_one()
    assert left == 0
