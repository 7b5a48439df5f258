"""Links to /ui job and batch pages, in headless chromium against the real API: a job's page has
an address (`/ui/jobs/{id}`, `/ui/batches/{id}`) that opens signed in in any tab of a browser that
signed in before, and in one that has not goes through the sign-in form and lands on that page.
The API key is never part of a URL."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest

from tests.integration.fixtures.services import ApiServer
from tests.services.conftest import scene_form
from tests.services.support.scene_factory import make_scene

pytestmark = [pytest.mark.integration, pytest.mark.slow]

JOB_TASKS = ["red blob"]
BATCH_TASKS = ["green blob"]


@pytest.fixture(scope="module")
def submitted(api_server: ApiServer, tmp_path_factory: pytest.TempPathFactory) -> tuple[str, str]:
    """(job id, batch id) of tenant A, submitted through the API (no worker needed: the pages
    show a queued job as well as a finished one)."""
    scene = make_scene(tmp_path_factory.mktemp("links") / "scene")
    with api_server.client("tenant-a") as client:
        resp = client.post("/v1/scenes", files=scene_form(scene))
        assert resp.status_code == 201, resp.text
        scene_id = resp.json()["id"]
        job = client.post("/v1/jobs", json={"scene_id": scene_id, "tasks": JOB_TASKS})
        assert job.status_code in (200, 201, 202), job.text
        batch = client.post("/v1/batches", json={"scene_ids": [scene_id], "task_lists": [BATCH_TASKS]})
        assert batch.status_code in (200, 201, 202), batch.text
    return job.json()["id"], batch.json()["id"]


@pytest.fixture
def context(browser) -> Iterator[object]:  # noqa: ANN001
    """A fresh browser context (its own storage: a browser that never signed in), whose every
    request URL is recorded so a test can check the key never went into one."""
    ctx = browser.new_context()
    ctx.urls = []  # type: ignore[attr-defined]
    ctx.on("request", lambda request: ctx.urls.append(request.url))  # type: ignore[attr-defined]
    yield ctx
    ctx.close()


def _sign_in(page, api: ApiServer) -> None:  # noqa: ANN001
    page.wait_for_selector("#api-key")
    page.fill("#api-key", api.keys["tenant-a"])
    page.click("#login")


def _shows_job(page, job_id: str) -> None:  # noqa: ANN001
    page.wait_for_function("document.getElementById('job-state').textContent.length > 0")
    assert page.text_content("#job-id") == job_id
    assert page.text_content("#job-tasks") == "; ".join(JOB_TASKS)
    assert page.text_content("#job-error") == ""


def _key_in_no_url(context, api: ApiServer) -> None:  # noqa: ANN001
    assert context.urls, "no request recorded"
    assert not [u for u in context.urls if api.keys["tenant-a"] in u]


def test_job_link_opens_signed_in_in_another_tab(
    api_server: ApiServer,
    submitted: tuple[str, str],
    context,  # noqa: ANN001
) -> None:
    job_id, _ = submitted
    first = context.new_page()
    first.goto(f"{api_server.base_url}/ui/")
    _sign_in(first, api_server)
    first.wait_for_selector("#app:not(.hidden)")
    first.wait_for_selector(f"#jobs a[href='/ui/jobs/{job_id}']")  # the jobs table links the address
    # the link pasted into another tab of the same browser: the job, no sign-in on the way
    other = context.new_page()
    other.goto(f"{api_server.base_url}/ui/jobs/{job_id}")
    _shows_job(other, job_id)
    assert other.url == f"{api_server.base_url}/ui/jobs/{job_id}"
    # the older address still works
    other.goto(f"{api_server.base_url}/ui/job?id={job_id}")
    _shows_job(other, job_id)
    _key_in_no_url(context, api_server)


def test_job_link_in_a_signed_out_browser_signs_in_then_lands_on_the_job(
    api_server: ApiServer,
    submitted: tuple[str, str],
    context,  # noqa: ANN001
) -> None:
    job_id, _ = submitted
    page = context.new_page()
    page.goto(f"{api_server.base_url}/ui/jobs/{job_id}")
    page.wait_for_url("**/ui/?next=*")
    assert page.is_visible("#login-section") and page.is_hidden("#app")
    _sign_in(page, api_server)
    page.wait_for_url(f"{api_server.base_url}/ui/jobs/{job_id}")
    _shows_job(page, job_id)
    _key_in_no_url(context, api_server)


def test_batch_link_in_a_signed_out_browser_signs_in_then_lands_on_the_batch(
    api_server: ApiServer,
    submitted: tuple[str, str],
    context,  # noqa: ANN001
) -> None:
    _, batch_id = submitted
    page = context.new_page()
    page.goto(f"{api_server.base_url}/ui/batches/{batch_id}")
    page.wait_for_url("**/ui/?next=*")
    _sign_in(page, api_server)
    page.wait_for_url(f"{api_server.base_url}/ui/batches/{batch_id}")
    page.wait_for_selector("#batch-jobs tbody tr[data-job]")
    assert page.text_content("#batch-id") == batch_id
    assert page.locator("#batch-jobs tbody tr").count() == 1
    job_link = page.get_attribute("#batch-jobs tbody tr a", "href")
    assert job_link is not None and job_link.startswith("/ui/jobs/")
    _key_in_no_url(context, api_server)


def test_a_key_the_api_refuses_goes_back_to_sign_in(
    api_server: ApiServer,
    submitted: tuple[str, str],
    context,  # noqa: ANN001
) -> None:
    """A stored key the API no longer accepts (revoked, rotated) is dropped, and the sign-in form
    shown with the way back to the page, not a page of errors."""
    job_id, _ = submitted
    page = context.new_page()
    page.goto(f"{api_server.base_url}/ui/")
    page.evaluate("localStorage.setItem('bfields-api-key', 'a-revoked-key')")
    page.goto(f"{api_server.base_url}/ui/jobs/{job_id}")
    page.wait_for_url("**/ui/?next=*")
    assert page.evaluate("localStorage.getItem('bfields-api-key')") is None
    _sign_in(page, api_server)
    page.wait_for_url(f"{api_server.base_url}/ui/jobs/{job_id}")
    _shows_job(page, job_id)


def test_sign_in_goes_on_only_to_a_ui_page(api_server: ApiServer, context) -> None:  # noqa: ANN001
    """`next` is followed only to a page of this site's /ui, never to another site."""
    page = context.new_page()
    for away in ("https://example.invalid/ui/", "//example.invalid/ui/", "/v1/jobs"):
        page.goto(f"{api_server.base_url}/ui/?next={away}")
        _sign_in(page, api_server)
        page.wait_for_selector("#app:not(.hidden)")
        assert page.url.startswith(f"{api_server.base_url}/ui/?next="), page.url
        page.click("#logout")


def test_job_and_batch_addresses_are_pages(api_server: ApiServer) -> None:
    for path in ("/ui/jobs/any-id", "/ui/batches/any-id"):
        resp = httpx.get(api_server.base_url + path)
        assert resp.status_code == 200 and resp.headers["content-type"].startswith("text/html"), path
    assert httpx.get(api_server.base_url + "/ui/jobs/", follow_redirects=True).status_code == 404
