"""FastAPI application factory: `create_app(settings)`; `bayesian_fields_service.api.app:app` for uvicorn.

The app holds one `AppState` (store, Redis, job store, key ring, Celery sender) built from the
settings, so tests and deployments differ only in `ServiceSettings`. Input errors become 422 with
the library's message (which names the file and the problem); nothing else leaks internals.
Every call the API makes to Redis, the broker or the bucket has a short, bounded retry budget
(`api_backend_timeout_s` x `api_backend_attempts`): an outage is answered 503 + Retry-After in
about a second (`bayesian_fields_service.api.edge`), while the workers keep their own patient retries.
"""

from __future__ import annotations

import redis
from fastapi import FastAPI
from redis.backoff import ConstantBackoff
from redis.retry import Retry

from bayesian_fields_service.api.edge import Utf8Guard, install_handlers
from bayesian_fields_service.api.routes import events, health, jobs, scenes, ui, usage
from bayesian_fields_service.api.routes.health import metrics_registry
from bayesian_fields_service.api.state import AppState
from bayesian_fields_service.api.sweeper import Sweeper, lifespan
from bayesian_fields_service.common.api_keys import ApiKeyRing
from bayesian_fields_service.common.jobs import JobStore
from bayesian_fields_service.common.settings import ServiceSettings, apply_log_level, get_settings
from bayesian_fields_service.common.storage import build_store
from bayesian_fields_service.records.database import open_records
from bayesian_fields_service.worker.celery_app import make_celery
from bayesian_fields_service.worker.dispatch import Dispatcher

DESCRIPTION = """
Bayesian Fields as a batch service: upload a scene (Gaussian splat + posed images), submit task
lists, poll, download the task-driven object map.

Authenticate every `/v1` call with `X-API-Key: <key>` (or `Authorization: Bearer <key>`).
Everything a key can see lives in its tenant's namespace; other tenants' ids answer 404.

Input rules: every string must be valid UTF-8 (a JSON `"\\ud800"` escape, a lone surrogate, is
refused with 422 naming the field, in bodies, query strings and the Idempotency-Key / API-key
headers). Tasks must not contain control characters (whitespace is collapsed to single spaces)
or bidirectional controls (U+202A-U+202E, U+2066-U+2069, U+200E/F, U+061C): refused, not
silently changed. Every numeric parameter is finite and bounded (see `PipelineParams` in the
job schema); NaN and Infinity are refused. When Redis or the bucket is down the API answers 503
with `Retry-After` within about a second; a refused submission leaves no job behind.
Every error body is a `Problem`: `detail` is a string, request validation adds `errors`.
"""


def _redis_client(settings: ServiceSettings) -> redis.Redis:
    """Redis for the request path: a bounded number of quick attempts, then the error (503)."""
    t = settings.api_backend_timeout_s
    return redis.Redis.from_url(
        settings.redis_url,
        socket_timeout=max(5.0, 5 * t),
        socket_connect_timeout=t,
        retry=Retry(ConstantBackoff(min(0.1, t / 4)), settings.api_backend_attempts - 1),
    )


def _worker_redis(settings: ServiceSettings) -> redis.Redis:
    """Redis for the dispatcher thread: patient, like a worker's (no request waits on it)."""
    return redis.Redis.from_url(settings.redis_url, socket_timeout=10, socket_connect_timeout=5)


def create_app(settings: ServiceSettings | None = None) -> FastAPI:
    settings = settings or get_settings()
    apply_log_level(settings)
    store = build_store(settings, request_path=True)
    client = _redis_client(settings)
    celery = make_celery(settings)
    t = settings.api_backend_timeout_s
    celery.conf.update(
        broker_connection_timeout=t,
        broker_connection_max_retries=settings.api_backend_attempts - 1,
        task_publish_retry_policy={
            "max_retries": settings.api_backend_attempts - 1,
            "interval_start": 0,
            "interval_step": min(0.1, t / 4),
            "interval_max": min(0.1, t / 4),
        },
        broker_transport_options={
            **celery.conf.broker_transport_options,
            "socket_connect_timeout": t,
            "socket_timeout": max(5.0, 5 * t),
        },
    )
    state = AppState(
        settings=settings,
        store=store,
        redis=client,
        jobs=JobStore(
            store, client, open_records(settings.database_url, migrate_first=settings.migrate_on_start)
        ),
        key_ring=ApiKeyRing.from_settings(settings),
        celery=celery,
    )
    state.metrics_registry = metrics_registry(state)
    dispatcher = Dispatcher(celery, state.jobs, settings, _worker_redis(settings))
    sweeper = lifespan(
        lambda: Sweeper(store, state.scenes, client, settings.orphan_max_age_s, settings.orphan_sweep_interval_s),
        also=dispatcher,  # releases waiting jobs to the workers (one API process at a time: a lease)
    )  # what a killed API left behind (see sweeper.py)
    app = FastAPI(title="Bayesian Fields API", version="1.0.0", description=DESCRIPTION, lifespan=sweeper)
    app.state.bf = state
    app.state.key_ring = state.key_ring
    for module in (scenes, jobs, health, ui, events, usage):
        app.include_router(module.router)
    install_handlers(app, settings.retry_after_s)
    app.add_middleware(Utf8Guard)
    return app


app: FastAPI  # declared only: the module's __getattr__ below makes it on first access


def __getattr__(name: str) -> FastAPI:
    """``app`` is built from the environment on first access (importing this module stays cheap)."""
    if name == "app":
        global app
        app = create_app()
        return app
    raise AttributeError(name)
