"""The /ui page as a person uses it, in headless chromium against the real service: log in with a
key, upload the sample scene with tasks, watch the job finish, see its preview (pixels checked on
a screenshot of the <img>), download links, a batch page with one row per scene and a thumbnail;
another tenant's key sees none of it."""

from __future__ import annotations

import time
import zipfile
from pathlib import Path

import httpx
import pytest

from tests.integration.fixtures.services import ApiServer
from tests.support.browser import pixels

pytestmark = [pytest.mark.integration, pytest.mark.slow]

SAMPLE = Path(__file__).resolve().parents[4] / "samples" / "tabletop"
TASKS = ["get the orange cone", "get the cyan cube"]
JOB_TIMEOUT_MS = 420_000


@pytest.fixture(scope="module")
def images_zip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("ui") / "images.zip"
    with zipfile.ZipFile(path, "w") as zf:
        for image in sorted((SAMPLE / "images").iterdir()):
            zf.write(image, image.name)
    return path


def _login(page, api: ApiServer, tenant: str) -> float:  # noqa: ANN001
    t0 = time.perf_counter()
    page.goto(f"{api.base_url}/ui/")
    page.wait_for_selector("#api-key")
    load_s = time.perf_counter() - t0
    page.fill("#api-key", api.keys[tenant])
    page.click("#login")
    page.wait_for_selector("#app:not(.hidden)")
    return load_s


def test_ui_flow(api_server: ApiServer, ui_workers, browser, images_zip: Path, tmp_path: Path) -> None:  # noqa: ANN001
    api = api_server
    ctx_a = browser.new_context(viewport={"width": 1200, "height": 900})
    page = ctx_a.new_page()
    # a wrong key is refused with the API's own message, and nothing is shown
    page.goto(f"{api.base_url}/ui/")
    page.fill("#api-key", "not-a-key")
    page.click("#login")
    page.wait_for_function("document.getElementById('login-error').textContent.length > 0")
    assert "API key" in page.text_content("#login-error")
    assert page.is_hidden("#app")

    load_s = _login(page, api, "tenant-a")
    page.fill("#scene-name", "tabletop")
    page.set_input_files("#splat", str(SAMPLE / "point_cloud.ply"))
    page.set_input_files("#cameras", str(SAMPLE / "transforms.json"))
    page.set_input_files("#images", str(images_zip))
    page.fill("#upload-tasks", "\n".join(TASKS))
    page.click("#upload")
    page.wait_for_function(
        "document.getElementById('upload-status').textContent.includes('submitted')", timeout=120_000
    )
    status = page.text_content("#upload-status")
    assert "21651 Gaussians, 20 frames" in status, status
    job_id = status.split("job ")[1].split()[0]
    # the jobs table polls until the job has succeeded
    page.wait_for_selector(f"tr[data-job='{job_id}'][data-state='succeeded']", timeout=JOB_TIMEOUT_MS)
    # a finished job's stage cell says it is done, not the last stage it ran ("cluster")
    assert page.text_content(f"tr[data-job='{job_id}'] td:nth-child(5)") == "done"

    t0 = time.perf_counter()
    page.goto(f"{api.base_url}/ui/job?id={job_id}")
    page.wait_for_function(
        "[...document.querySelectorAll('#previews img')].length == 2 && "
        "[...document.querySelectorAll('#previews img')].every(i => i.complete && i.naturalWidth > 0)",
        timeout=60_000,
    )
    job_page_s = time.perf_counter() - t0
    assert page.text_content("#job-state") == "succeeded"
    assert page.text_content("#job-stage") == "done"  # it said "cluster", the last stage run
    img = page.locator(f"#previews img[data-task='{TASKS[0]}']")
    shot = pixels(img.screenshot())
    assert shot.shape[0] > 100 and shot.std() > 20, "the preview is blank"
    # rank-1 outline/tint (red) and the legend strip (near-black) are in the picture
    red = (shot[..., 0] > 180) & (shot[..., 1] < 120) & (shot[..., 2] < 110)
    assert red.sum() > 30, red.sum()
    assert (shot[-20:].mean(axis=(0, 1)) < 60).all()
    # one table per task: rank, object, p, Gaussians and box of each selected object, as the result says
    result = httpx.get(f"{api.base_url}/v1/jobs/{job_id}/result", headers=api.headers("tenant-a")).json()
    selections = {sel["task"]: sel["objects"] for sel in result["summary"]["selections"]}
    assert page.eval_on_selector_all("table.objects", "ts => ts.map(t => t.dataset.task)") == TASKS
    for task in TASKS:
        shown = page.eval_on_selector_all(
            f"table.objects[data-task='{task}'] tbody tr",
            "rows => rows.map(r => [...r.cells].map(c => c.textContent))",
        )
        assert len(shown) == len(selections[task]) > 0
        for rank, (cells, obj) in enumerate(zip(shown, selections[task], strict=True)):
            assert cells[:4] == [f"#{rank + 1}", str(obj["object_id"]), f"{obj['probability']:.3f}",
                                 str(obj["num_gaussians"])]  # fmt: skip
            assert cells[4] == "(" + ", ".join(f"{c:.3f}" for c in obj["box"]["center"]) + ")"
            assert cells[6] == Path(obj["export"]).name
    # every file stays one click away, folded under the tables
    assert page.is_hidden("#downloads")
    if _shots():
        page.screenshot(path=str(Path(__file__).resolve().parents[4] / "docs" / "ui-job.png"), full_page=True)
    page.click("#files summary")
    links = page.eval_on_selector_all("#downloads a", "as => as.map(a => a.dataset.path)")
    assert sorted(links) == sorted(a["path"] for a in result["artifacts"])
    with page.expect_download() as download:
        page.click("#downloads a[data-path='result/summary.json']")
    single = Path(download.value.path()).read_bytes()
    assert b'"previews"' in single
    # "download all": one zip of every file, byte for byte
    with page.expect_download() as download:
        page.click("#download-all")
    assert download.value.suggested_filename == f"{job_id}.zip"
    with zipfile.ZipFile(download.value.path()) as archive:
        assert sorted(archive.namelist()) == sorted(links)
        assert archive.read("result/summary.json") == single

    # a batch of the same scene: one row per scene, finished, with a thumbnail
    page.goto(f"{api.base_url}/ui/")
    page.wait_for_selector("#app:not(.hidden)")
    page.wait_for_selector("input.pick")
    page.check("input.pick")
    page.fill("#job-tasks", TASKS[1])
    page.click("#submit-batch")
    page.wait_for_selector("#batches a")
    page.click("#batches a")
    page.wait_for_selector("body[data-finished='true']", timeout=JOB_TIMEOUT_MS)
    # the page follows the batch's server-sent-event stream (no polling) until its `end` event
    page.wait_for_selector("body[data-stream='ended']", timeout=JOB_TIMEOUT_MS)
    assert int(page.evaluate("document.body.dataset.events")) >= 3  # job(s), counts, end
    rows = page.locator("#batch-jobs tbody tr")
    assert rows.count() == 1
    assert rows.first.get_attribute("data-state") == "succeeded"
    assert rows.first.locator("td").nth(3).text_content() == "done"
    assert "tabletop" in rows.first.text_content()
    page.wait_for_function(
        "(() => { const i = document.querySelector('#batch-jobs img.thumb'); return i && i.complete && i.naturalWidth > 0; })()"
    )
    if _shots():
        page.screenshot(
            path=str(Path(__file__).resolve().parents[4] / "docs" / "ui-batch.png"), full_page=True
        )

    # another tenant sees nothing of it, on the page or through the API the page uses
    ctx_b = browser.new_context()
    page_b = ctx_b.new_page()
    _login(page_b, api, "tenant-b")
    page_b.wait_for_timeout(2000)
    assert page_b.locator(f"tr[data-job='{job_id}']").count() == 0
    assert page_b.locator("#scenes tbody tr").count() == 0
    page_b.goto(f"{api.base_url}/ui/job?id={job_id}")
    page_b.wait_for_function("document.getElementById('job-error').textContent.length > 0")
    assert "not found" in page_b.text_content("#job-error")
    assert page_b.locator("#previews img").count() == 0
    for route in ("result", "result.zip"):
        resp = httpx.get(f"{api.base_url}/v1/jobs/{job_id}/{route}", headers=api.headers("tenant-b"))
        assert resp.status_code == 404, route
    ctx_a.close()
    ctx_b.close()
    _view_job(api, job_id, tmp_path)
    print(f"/ui load {load_s * 1000:.0f} ms; job page with previews {job_page_s * 1000:.0f} ms")


def _view_job(api: ApiServer, job_id: str, tmp_path: Path) -> None:
    """`bfields view --job`: the job's result comes through the client; the scene's geometry from
    the result's own export (the scene folder is not on this machine), or from --scene."""
    pytest.importorskip("viser")
    from argparse import Namespace

    from bayesian_fields_core.cli.view_command import _fetch_job
    from bayesian_fields_core.viewer.data import load_view

    args = Namespace(
        job=job_id, server=api.base_url, api_key=api.keys["tenant-a"], download_dir=str(tmp_path / "dl")
    )
    folder = _fetch_job(args)
    data = load_view(folder)
    assert data.total_gaussians == 21651 and data.frames == [] and data.tasks == TASKS
    assert data.summary["scene"]["store_prefix"].endswith("/input/")
    assert len(load_view(folder, scene_dir=SAMPLE).frames) == 20
    from bayesian_fields_core.errors import InputError

    with pytest.raises(InputError, match="not found"):
        _fetch_job(
            Namespace(
                job=job_id,
                server=api.base_url,
                api_key=api.keys["tenant-b"],
                download_dir=str(tmp_path / "b"),
            )
        )


def _shots() -> bool:
    import os

    return os.environ.get("BFIELDS_UI_SCREENSHOTS") == "1"


def test_ui_pages_need_no_key_but_hold_no_data(api_server: ApiServer) -> None:
    for path in ("/ui/", "/ui/job", "/ui/batch", "/ui/app.js", "/ui/style.css"):
        resp = httpx.get(api_server.base_url + path)
        assert resp.status_code == 200, path
    assert httpx.get(api_server.base_url + "/ui/nope").status_code == 404
    html = httpx.get(api_server.base_url + "/ui/").text
    assert "http://" not in html and "https://" not in html  # nothing from a CDN
