"""Liveness, readiness (Redis and the bucket answer) and Prometheus metrics."""

from __future__ import annotations

from collections.abc import Iterator

import redis
from fastapi import APIRouter, Depends, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import GaugeMetricFamily, HistogramMetricFamily
from prometheus_client.registry import Collector

from bayesian_fields_service.api.schemas import Health
from bayesian_fields_service.api.state import AppState, get_state
from bayesian_fields_service.common.jobs import STAGES, JobState
from bayesian_fields_service.common.metrics import (
    JOB_KEY,
    QUEUE_WAIT_KEY,
    STAGE_KEY,
    queue_wait_tenants,
    read_histogram,
)
from bayesian_fields_service.worker.dispatch import queue_length

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="Liveness: the process answers")
def healthz() -> Health:
    return Health(status="ok")


@router.get(
    "/readyz",
    response_model=Health,
    summary="Readiness: Redis and the bucket answer",
    responses={503: {"model": Health}},
)
def readyz(state: AppState = Depends(get_state)) -> JSONResponse:
    checks = {}
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
    return JSONResponse(body.model_dump(), status_code=200 if ok else 503)


class ServiceCollector(Collector):
    """Reads queue depths and the workers' Redis histograms at scrape time."""

    def __init__(self, state: AppState) -> None:
        self.state = state

    def collect(self) -> Iterator:
        s = self.state
        depth = GaugeMetricFamily(
            "bfields_queue_depth", "Messages waiting in a Celery queue.", labels=["queue"]
        )
        active = GaugeMetricFamily("bfields_jobs_active", "Jobs whose record is queued or running.")
        stage_h = HistogramMetricFamily(
            "bfields_stage_seconds", "Duration of finished stages.", labels=["stage"]
        )
        job_h = HistogramMetricFamily(
            "bfields_job_seconds", "Duration of finished jobs by outcome.", labels=["outcome"]
        )
        waiting = GaugeMetricFamily(
            "bfields_jobs_waiting",
            "Jobs waiting in a tenant's fair-share queue, not yet dispatched to a Celery queue "
            "(autoscaling adds this to bfields_queue_depth; see deploy/keda.yaml).",
            labels=["tenant"],
        )
        wait_h = HistogramMetricFamily(
            "bfields_queue_wait_seconds",
            "Seconds from a job's submission to its dispatch to a worker queue.",
            labels=["tenant"],
        )
        try:
            for queue in {s.settings.gpu_queue, s.settings.cpu_queue}:
                depth.add_metric([queue], queue_length(s.redis, queue))
            for stage in STAGES:
                if (h := read_histogram(s.redis, STAGE_KEY.format(stage=stage))) is not None:
                    stage_h.add_metric([stage], h[0], h[1])
            for outcome in (JobState.succeeded, JobState.failed, JobState.cancelled):
                if (h := read_histogram(s.redis, JOB_KEY.format(outcome=outcome.value))) is not None:
                    job_h.add_metric([outcome.value], h[0], h[1])
            counts = s.jobs.queue.waiting_by_tenant()
            for tenant, n in sorted(counts.items()):
                waiting.add_metric([tenant], n)
            if not counts:  # a series even when nothing waits, so sum() in a query is 0, not empty
                waiting.add_metric([""], 0)
            for tenant in queue_wait_tenants(s.redis):
                if (h := read_histogram(s.redis, QUEUE_WAIT_KEY.format(tenant=tenant))) is not None:
                    wait_h.add_metric([tenant], h[0], h[1])
        except redis.RedisError:
            return
        active.add_metric([], s.jobs.count_active())
        yield from (depth, active, stage_h, job_h, waiting, wait_h)


def metrics_registry(state: AppState) -> CollectorRegistry:
    registry = CollectorRegistry(auto_describe=False)
    registry.register(ServiceCollector(state))
    return registry


@router.get("/metrics", summary="Prometheus metrics", response_class=Response)
def metrics(state: AppState = Depends(get_state)) -> Response:
    return Response(generate_latest(state.metrics_registry), media_type=CONTENT_TYPE_LATEST)
