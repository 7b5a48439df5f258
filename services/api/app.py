"""FastAPI application factory: `create_app(settings)`; `services.api.app:app` for uvicorn.

The app holds one `AppState` (store, Redis, job store, key ring, Celery sender) built from the
settings, so tests and deployments differ only in `ServiceSettings`. Input errors become 422 with
the library's message (which names the file and the problem); nothing else leaks internals.
"""

from __future__ import annotations

import redis
from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from bayesian_fields_core.errors import InputError
from services.common.api_keys import ApiKeyRing
from services.common.jobs import JobStore
from services.common.settings import ServiceSettings, apply_log_level, get_settings
from services.common.storage import build_store
from services.worker.celery_app import make_celery

from .routes import health, jobs, scenes, ui
from .routes.health import metrics_registry
from .state import AppState

DESCRIPTION = """
Bayesian Fields as a batch service: upload a scene (Gaussian splat + posed images), submit task
lists, poll, download the task-driven object map.

Authenticate every `/v1` call with `X-API-Key: <key>` (or `Authorization: Bearer <key>`).
Everything a key can see lives in its tenant's namespace; other tenants' ids answer 404.
"""


def create_app(settings: ServiceSettings | None = None) -> FastAPI:
    settings = settings or get_settings()
    apply_log_level(settings)
    store = build_store(settings)
    client = redis.Redis.from_url(settings.redis_url, socket_timeout=10, socket_connect_timeout=5)
    state = AppState(
        settings=settings,
        store=store,
        redis=client,
        jobs=JobStore(store, client),
        key_ring=ApiKeyRing.from_settings(settings),
        celery=make_celery(settings),
    )
    state.metrics_registry = metrics_registry(state)
    app = FastAPI(title="Bayesian Fields API", version="1.0.0", description=DESCRIPTION)
    app.state.bf = state
    app.state.key_ring = state.key_ring
    for module in (scenes, jobs, health, ui):
        app.include_router(module.router)

    @app.exception_handler(InputError)
    async def _input_error(request: Request, exc: InputError) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=422)

    return app


def __getattr__(name: str) -> FastAPI:
    """``app`` is built from the environment on first access (importing this module stays cheap)."""
    if name == "app":
        global app
        app = create_app()
        return app
    raise AttributeError(name)
