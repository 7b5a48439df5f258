"""`/ui`: the service's web page for people (scenes, jobs, batches, previews, downloads).

The pages are static HTML + one vanilla-JS file + one stylesheet, shipped as package data in
`services/api/ui/` (no CDN, no build step). They carry no data and need no key: the page asks for
an API key, keeps it in the browser's localStorage and sends it as `X-API-Key` to the same JSON API
any client uses, so authentication and tenant isolation are the API's own. Previews and exports
are fetched with that header too (or through the presigned links the API returns), never through a
UI route.

A job's page is `/ui/jobs/{id}` and a batch's `/ui/batches/{id}` (the older `/ui/job?id=` and
`/ui/batch?id=` still work): addresses a person can share, that open in any browser signed in to
this site, and on one that is not, go through the sign-in form and come back (`/ui/?next=...`).
The key is never part of a URL, so links do not leak it into history, logs or referrers.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, HTTPException
from fastapi.responses import FileResponse, RedirectResponse

UI_DIR = Path(__file__).resolve().parent.parent / "ui"
PAGES = {"": "index.html", "job": "job.html", "batch": "batch.html"}
ASSETS = {"app.js": "text/javascript", "style.css": "text/css"}

router = APIRouter(prefix="/ui", tags=["ui"], include_in_schema=False)

_NO_STORE = {
    "Cache-Control": "no-cache",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}


@router.get("")
def ui_root() -> RedirectResponse:
    return RedirectResponse("/ui/")


@router.get("/{name}")
def ui_page(name: str) -> FileResponse:
    """A page (`/ui/`, `/ui/job`, `/ui/batch`) or one of its two assets."""
    if name in PAGES:
        return FileResponse(UI_DIR / PAGES[name], media_type="text/html", headers=_NO_STORE)
    if name in ASSETS:
        return FileResponse(UI_DIR / name, media_type=ASSETS[name], headers=_NO_STORE)
    raise HTTPException(404, f"no page {name!r} (pages: /ui/, /ui/jobs/ID, /ui/batches/ID)")


@router.get("/jobs/{job_id}")
def ui_job_page(job_id: str) -> FileResponse:
    """A job's page; the id is read by the page's script, which asks the API for the job."""
    return FileResponse(UI_DIR / PAGES["job"], media_type="text/html", headers=_NO_STORE)


@router.get("/batches/{batch_id}")
def ui_batch_page(batch_id: str) -> FileResponse:
    """A batch's page; the id is read by the page's script, which asks the API for the batch."""
    return FileResponse(UI_DIR / PAGES["batch"], media_type="text/html", headers=_NO_STORE)


@router.get("/")
def ui_index() -> FileResponse:
    return FileResponse(UI_DIR / "index.html", media_type="text/html", headers=_NO_STORE)
