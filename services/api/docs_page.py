"""``/docs``: the Swagger UI page, its scripts and styles served by the API itself.

Why: FastAPI's page loads Swagger UI from a CDN (cdn.jsdelivr.net) and its favicon from
fastapi.tiangolo.com, so on a machine or cluster without internet ``/docs`` was a blank page. The
assets come from the `swagger-ui-bundle` package (in the ``api`` extra; Swagger UI 4, Apache-2.0)
and are served under `ASSETS`; the page names no other host. ReDoc (``/redoc``, CDN-only) is off;
``/openapi.json`` is the document itself for any other viewer.
"""

from __future__ import annotations

from fastapi import FastAPI
from fastapi.openapi.docs import get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles
from swagger_ui_bundle import swagger_ui_path

#: Where the Swagger UI files are served from.
ASSETS = "/docs/assets"


def install_docs(app: FastAPI, title: str) -> None:
    """Serve ``/docs`` (and its OAuth2 redirect page) from local assets; the app must be created
    with ``docs_url=None, redoc_url=None``."""
    app.mount(ASSETS, StaticFiles(directory=swagger_ui_path), name="swagger-ui-assets")
    redirect = "/docs/oauth2-redirect"

    @app.get("/docs", include_in_schema=False)
    def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title=f"{title} - docs",
            swagger_js_url=f"{ASSETS}/swagger-ui-bundle.js",
            swagger_css_url=f"{ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{ASSETS}/favicon-32x32.png",
            oauth2_redirect_url=redirect,
        )

    @app.get(redirect, include_in_schema=False)
    def oauth2_redirect() -> HTMLResponse:
        return get_swagger_ui_oauth2_redirect_html()
