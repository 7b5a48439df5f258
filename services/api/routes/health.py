"""Liveness and readiness: the process answers; PostgreSQL, Redis and the bucket answer."""

from __future__ import annotations

import redis
from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse

from bayesian_fields_service.api.records_outage import OUTAGES
from bayesian_fields_service.api.schemas import Health
from bayesian_fields_service.api.state import AppState, get_state
from bayesian_fields_service.records.database import ping

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="Liveness: the process answers")
def healthz() -> Health:
    return Health(status="ok")


def _postgresql(state: AppState) -> str:
    """``SELECT 1`` on the records database: a pooled connection (pre-pinged), or a new one within
    the engine's connect timeout (`records.database.CONNECT_TIMEOUT_S`)."""
    try:
        ping(state.jobs.database)
        return "ok"
    except OUTAGES as exc:
        return f"error: {type(exc).__name__}"


@router.get(
    "/readyz",
    response_model=Health,
    summary="Readiness: PostgreSQL, Redis and the bucket answer (503 naming each one that does not)",
    responses={503: {"model": Health}},
)
def readyz(state: AppState = Depends(get_state)) -> JSONResponse:
    checks = {"postgresql": _postgresql(state)}
    try:
        state.redis.ping()
        checks["redis"] = "ok"
    except redis.RedisError as exc:
        checks["redis"] = f"error: {type(exc).__name__}"
    try:
        state.store.list("readyz-probe/")
        checks["storage"] = "ok"
    except Exception as exc:  # any storage failure means not ready; the type is enough detail
        checks["storage"] = f"error: {type(exc).__name__}"
    ok = all(v == "ok" for v in checks.values())
    body = Health(status="ok" if ok else "degraded", checks=checks)
    headers = None if ok else {"Retry-After": str(state.settings.retry_after_s)}
    return JSONResponse(body.model_dump(), status_code=200 if ok else 503, headers=headers)
