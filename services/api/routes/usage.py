"""``GET /v1/usage``: what the caller's tenant used per day (UTC) and over a period.

The totals come from the usage ledger (`jobs/usage.py`): CPU-seconds and GPU-seconds of every
stage execution by stage, jobs ended by outcome, and the bytes the ended jobs left stored. A key
sees only its own tenant's usage, like every other route.
"""

from __future__ import annotations

from datetime import UTC, date, datetime
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query
from pydantic import BaseModel, Field

from bayesian_fields_service.api.query import Day
from bayesian_fields_service.api.state import ERRORS, State, Tenant

router = APIRouter(prefix="/v1", tags=["usage"])


class StageUsage(BaseModel):
    cpu_seconds: float = 0.0
    gpu_seconds: float = 0.0


class UsageTotals(BaseModel):
    jobs: int = Field(0, description="Jobs that ended (any outcome).")
    jobs_by_state: dict[str, int] = Field(default_factory=dict)
    stage_runs: int = Field(0, description="Stage executions counted (retries included).")
    cpu_seconds: float = 0.0
    gpu_seconds: float = 0.0
    bytes_stored: int = Field(0, description="Bytes the ended jobs left under their prefixes.")
    by_stage: dict[str, StageUsage] = Field(default_factory=dict)


class DayUsage(UsageTotals):
    day: date


class UsageReport(BaseModel):
    tenant: str
    from_: date = Field(alias="from", serialization_alias="from")
    to: date
    total: UsageTotals
    days: list[DayUsage] = Field(description="Days with any usage, oldest first.")

    model_config = {"populate_by_name": True}


@router.get(
    "/usage",
    response_model=UsageReport,
    response_model_by_alias=True,
    summary="The caller's usage (CPU / GPU seconds, jobs, bytes) per day and over a period",
    responses=ERRORS,
)
def get_usage(
    tenant: Tenant,
    state: State,
    start: Annotated[
        Day,
        Query(alias="from", description="First day (UTC, inclusive); default: the 1st of `to`'s month"),
    ] = None,
    end: Annotated[Day, Query(alias="to", description="Last day (UTC, inclusive); default: today")] = None,
) -> UsageReport:
    end = end or datetime.now(UTC).date()
    start = start or end.replace(day=1)
    if start > end:
        raise HTTPException(422, f"from ({start}) is after to ({end})")
    days = (end - start).days + 1
    if days > state.settings.usage_max_days:
        raise HTTPException(
            422, f"{days} days; at most {state.settings.usage_max_days} per request (BFIELDS_USAGE_MAX_DAYS)"
        )
    report = state.jobs.tenant_usage(tenant, start, end)
    return UsageReport.model_validate(report)
