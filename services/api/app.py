"""FastAPI application factory: `create_app(settings)`; `bayesian_fields_service.api.app:app` for uvicorn.

The app holds one `AppState` (the domains over one bucket, Redis client and records engine, and
the key ring) built from the settings, so tests and deployments differ only in `ServiceSettings`. Input errors become 422 with the
library's message (which names the file and the problem); nothing else leaks internals. The API
serves HTTP only: a stored job waits in the jobs table until the control process dispatches it.
Every call the API makes to Redis or the bucket has a short, bounded retry budget
(`api_backend_timeout_s` x `api_backend_attempts`): an outage is answered 503 + Retry-After in
about a second (`bayesian_fields_service.api.edge`), while the workers keep their own patient retries.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Callable

import redis
from fastapi import FastAPI
from redis.backoff import ConstantBackoff
from redis.retry import Retry
from starlette.datastructures import Headers
from starlette.types import Scope

from bayesian_fields_core.errors import InputError
from bayesian_fields_service import hooks
from bayesian_fields_service.api.body_deadline import BodyDeadline
from bayesian_fields_service.api.bulk_lane import BulkLane, settle_child
from bayesian_fields_service.api.docs_page import install_docs
from bayesian_fields_service.api.edge import Utf8Guard, install_handlers
from bayesian_fields_service.api.json_body import add_body_schemas
from bayesian_fields_service.api.problems import describe_problems, install_problem_page
from bayesian_fields_service.api.routes import answers, events, health, jobs, metrics, scenes, ui, usage
from bayesian_fields_service.api.routes.metrics import metrics_registry
from bayesian_fields_service.api.schemas import BatchRequest
from bayesian_fields_service.api.state import AppState
from bayesian_fields_service.api.tenant_gate import TenantFairness, TenantGate
from bayesian_fields_service.api.tenant_rate import TenantRate
from bayesian_fields_service.config.settings import ServiceSettings, apply_log_level, get_settings
from bayesian_fields_service.observability import logs, tracing
from bayesian_fields_service.records.database import open_records
from bayesian_fields_service.scenes.upload_temp import Sweeper
from bayesian_fields_service.security.api_keys import ApiKeyRing
from bayesian_fields_service.security.auth import key_in_headers
from bayesian_fields_service.storage.stores import build_store

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
job schema); NaN and Infinity are refused. Query values are checked too: filters and cursors are
the service's own ids or positions (ASCII digits), usage days fall in 2000..2999, no value holds a
NUL; anything else is a 422 naming the parameter. When the records database (PostgreSQL), Redis or
the bucket is down the API answers 503 with `Retry-After`, never 500; a refused submission leaves
no job behind.
Every error body is a `Problem` (RFC 9457, `application/problem+json`): `type` names the kind of
error (a section of `/docs/errors`), `detail` is a string, request validation adds `errors`.
Submissions carry the tenant's job quota in `RateLimit-Policy` / `RateLimit` (IETF httpapi draft);
every 429 and 503 carries `Retry-After`.
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


def _lifespan(state: AppState) -> Callable[[FastAPI], contextlib.AbstractAsyncContextManager[None]]:
    """What runs beside the app while it serves: the sweeper of what a killed request of this
    process left in its temp folder (sweeper.py), and the bulk lane (bulk_lane.py). The dispatcher
    and every other background loop run in the control process."""
    settings = state.settings

    @contextlib.asynccontextmanager
    async def run(_: FastAPI) -> AsyncIterator[None]:
        sweeper = Sweeper(settings.orphan_max_age_s, settings.orphan_sweep_interval_s)
        sweeper.start()
        lane = BulkLane(wait_s=settings.api_bulk_lane_wait_s) if settings.api_bulk_lane else None
        if lane is not None:
            lane.start()
        state.bulk_lane = lane
        try:
            yield
        finally:
            state.bulk_lane = None
            if lane is not None:
                await lane.aclose()
                lane.stop()
            sweeper.stop()

    return run


def create_lane_app() -> FastAPI:
    """The app of an API process's bulk lane child (bulk_lane.py): the same app with the lane off,
    at a lower CPU priority, and stopping with the API process."""
    settle_child()
    return create_app(get_settings().model_copy(update={"api_bulk_lane": False}))


def _tenant_of(ring: ApiKeyRing) -> Callable[[Scope], str | None]:
    """The tenant of a request's API key, from its raw headers (the fairness middleware runs
    before any route); None for no key or an unknown one."""

    def tenant_of(scope: Scope) -> str | None:
        headers = Headers(scope=scope)
        try:
            return ring.tenant_for(key_in_headers(headers.get("x-api-key"), headers.get("authorization")))
        except InputError:  # an unreadable keys file: the route's authentication answers it
            return None

    return tenant_of


def create_app(settings: ServiceSettings | None = None) -> FastAPI:
    settings = settings or get_settings()
    apply_log_level(settings)
    logs.configure(settings)
    tracing.configure(settings, "api")  # before the engine and clients are made
    hooks.install(settings)
    store = build_store(settings, request_path=True)
    client = _redis_client(settings)
    state = AppState.open(
        settings,
        store,
        client,
        open_records(settings.database_url, migrate_first=settings.migrate_on_start),
        key_ring=ApiKeyRing.from_settings(settings),
        tenant_gate=TenantGate(
            settings.api_tenant_concurrency,
            settings.api_tenant_queue,
            settings.api_tenant_streams,
            TenantRate(settings.api_tenant_rate, settings.api_tenant_burst, settings.api_tenant_rate_delay_s),
        ),
    )
    state.metrics_registry = metrics_registry(state)
    app = FastAPI(
        title="Bayesian Fields API",
        version="1.0.0",
        description=DESCRIPTION,
        lifespan=_lifespan(state),
        docs_url=None,  # served from local assets by install_docs (docs_page.py says why)
        redoc_url=None,
    )
    install_docs(app, app.title)
    app.state.bf = state
    app.state.key_ring = state.key_ring
    for module in (scenes, jobs, answers, health, metrics, ui, events, usage):
        app.include_router(module.router)
    add_body_schemas(app, [BatchRequest])  # the bodies routes parse themselves (json_body.py)
    install_handlers(app, settings.retry_after_s)
    install_problem_page(app)  # what every error's `type` points at (problems.py)
    describe_problems(app)
    app.add_middleware(Utf8Guard)
    # every read of a body, the UTF-8 check's included, has its deadline (body_deadline.py says why)
    app.add_middleware(
        BodyDeadline, timeout_s=settings.api_body_timeout_s, min_rate_bytes=settings.api_body_min_rate_bytes
    )
    # added last, so it is the outermost: a tenant's request past its bound waits (or is refused)
    # before anything else works on it (tenant_gate.py says why)
    app.add_middleware(
        TenantFairness,
        gate=state.tenant_gate,
        tenant_of=_tenant_of(state.key_ring),
        retry_after_s=settings.retry_after_s,
    )
    tracing.instrument_app(app)  # outermost: the request's span covers the whole answer
    return app


app: FastAPI  # declared only: the module's __getattr__ below makes it on first access


def __getattr__(name: str) -> FastAPI:
    """``app`` is built from the environment on first access (importing this module stays cheap)."""
    if name == "app":
        global app
        app = create_app()
        return app
    raise AttributeError(name)
