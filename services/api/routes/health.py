"""Liveness and readiness: the process answers; PostgreSQL, Redis and the bucket answer (each
probed by the state's `Readiness`, `api/readiness.py`)."""

from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse

from bayesian_fields_service.api.schemas import Health
from bayesian_fields_service.api.state import AppState, get_state

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="Liveness: the process answers")
def healthz() -> Health:
    return Health(status="ok")


@router.get(
    "/readyz",
    response_model=Health,
    summary="Readiness: PostgreSQL, Redis and the bucket answer (503 naming each one that does not)",
    responses={503: {"model": Health}},
)
def readyz(state: AppState = Depends(get_state)) -> JSONResponse:
    checks = state.readiness.check()  # api/readiness.py: one status per component
    ok = all(v == "ok" for v in checks.values())
    body = Health(status="ok" if ok else "degraded", checks=checks)
    headers = None if ok else {"Retry-After": str(state.settings.retry_after_s)}
    return JSONResponse(body.model_dump(), status_code=200 if ok else 503, headers=headers)
