"""``GET /metrics``: Prometheus metrics, for the operator's scraper only.

Why a token of its own: the metrics describe every tenant's work (and, per tenant, who the
tenants are and how much each has waiting), so an API key, which any tenant holds, must not
open them, and neither may no key at all. The route answers only to ``Authorization: Bearer
<metrics_token>``, or to anyone where the operator says the port is theirs alone
(`metrics_anonymous`); with neither set it does not exist (404). Per-tenant series are an
operator's choice too (`metrics_per_tenant`); by default each series sums over the tenants.
"""

from __future__ import annotations

import hmac
from collections.abc import Iterator

from fastapi import APIRouter, Depends, HTTPException, Request, Response, status
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily
from prometheus_client.registry import Collector

from bayesian_fields_core.job.stage_table import STAGES
from bayesian_fields_service.api.records_outage import OUTAGES
from bayesian_fields_service.api.state import AppState, get_state
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.jobs.model import JobState
from bayesian_fields_service.live.metrics import Histogram, LiveReading

router = APIRouter(tags=["health"])


def _summed(histograms: list[Histogram]) -> Histogram | None:
    """One histogram over all tenants: the same buckets, their counts and sums added."""
    if not histograms:
        return None
    buckets = [(bound, sum(h[0][i][1] for h in histograms)) for i, (bound, _) in enumerate(histograms[0][0])]
    return buckets, sum(h[1] for h in histograms), sum(h[2] for h in histograms)


class ServiceCollector(Collector):
    """Reads queue depths and the workers' Redis histograms (`state.live_metrics`) and the fleet's
    rows (`JobStore.fleet_rows`) at scrape time. Each source is read once per scrape and may be
    down: its ``bfields_*_up`` gauge is then 0 and its families are left out, and the scrape still
    answers 200 (an alert on ``bfields_database_up == 0`` needs a scrape that says so)."""

    def __init__(self, state: AppState) -> None:
        self.state = state

    def collect(self) -> Iterator:
        s = self.state
        per_tenant = s.settings.metrics_per_tenant
        yield from self._tenant_gate(per_tenant)
        live = s.live_metrics.read(
            {s.settings.gpu_queue, s.settings.cpu_queue},
            STAGES,
            (state.value for state in JobState if state.terminal),
        )
        redis_up = GaugeMetricFamily(
            "bfields_redis_up", "1 when Redis (live state and broker) answered this scrape, else 0."
        )
        redis_up.add_metric([], 0 if live is None else 1)
        yield redis_up
        if live is not None:  # Redis does not answer: its families are left out
            yield from self._live(live, per_tenant)
        yield from self._records(per_tenant)

    def _live(self, live: LiveReading, per_tenant: bool) -> Iterator:
        """The families read from Redis: queue depths and the histograms the workers keep there."""
        tenant_label = ["tenant"] if per_tenant else []
        depth = GaugeMetricFamily(
            "bfields_queue_depth", "Messages waiting in a Celery queue.", labels=["queue"]
        )
        stage_h = HistogramMetricFamily(
            "bfields_stage_seconds", "Duration of finished stages.", labels=["stage"]
        )
        job_h = HistogramMetricFamily(
            "bfields_job_seconds", "Duration of finished jobs by outcome.", labels=["outcome"]
        )
        wait_h = HistogramMetricFamily(
            "bfields_queue_wait_seconds",
            "Seconds from a job's submission to its dispatch to a worker queue "
            "(per tenant where BFIELDS_METRICS_PER_TENANT is on).",
            labels=tenant_label,
        )
        stage_wait_h = HistogramMetricFamily(
            "bfields_stage_queue_wait_seconds",
            "Seconds a stage's message waited in its Celery queue: from its publication (dispatch, "
            "the previous stage's end, or a retry's due time) to its start on a worker.",
            labels=["stage"],
        )
        memory_h = HistogramMetricFamily(
            "bfields_stage_gpu_memory_peak_bytes",
            "Peak GPU memory (torch.cuda.max_memory_allocated) of each ended stage execution; "
            "0 on CPU workers.",
            labels=["stage"],
        )
        gpu_s = CounterMetricFamily(
            "bfields_stage_gpu_seconds_total",
            "GPU-seconds of ended stage executions (their wall time on a CUDA worker; 0 on CPU workers).",
            labels=["stage"],
        )
        cpu_s = CounterMetricFamily(
            "bfields_stage_cpu_seconds_total", "CPU-seconds of ended stage executions.", labels=["stage"]
        )
        for queue, n in live.queue_depths.items():
            depth.add_metric([queue], n)
        for stage, h in live.stages.items():
            stage_h.add_metric([stage], h[0], h[1])
        for outcome, h in live.jobs.items():
            job_h.add_metric([outcome], h[0], h[1])
        for stage, h in live.stage_queue_waits.items():
            stage_wait_h.add_metric([stage], h[0], h[1])
        for stage, h in live.stage_gpu_memory.items():
            memory_h.add_metric([stage], h[0], h[1])
        for stage, used in live.stage_usage.items():
            gpu_s.add_metric([stage], used["gpu_s"])
            cpu_s.add_metric([stage], used["cpu_s"])
        if per_tenant:
            for tenant, h in live.queue_waits.items():
                wait_h.add_metric([tenant], h[0], h[1])
        elif (total := _summed(list(live.queue_waits.values()))) is not None:
            wait_h.add_metric([], total[0], total[1])
        yield from (depth, stage_h, job_h, wait_h, stage_wait_h, memory_h, gpu_s, cpu_s)

    def _records(self, per_tenant: bool) -> Iterator:
        """The families read from PostgreSQL: jobs by state, the waiting jobs, the callback outbox,
        the leader's lease and the stalled jobs; with ``bfields_database_up`` 0 and none of them
        when the database does not answer (within its connect timeout)."""
        s = self.state
        up = GaugeMetricFamily(
            "bfields_database_up", "1 when the records database (PostgreSQL) answered this scrape, else 0."
        )
        try:
            rows = s.jobs.fleet_rows(s.settings.stage_lock_ttl_s)
            counts = s.jobs.queue.waiting_by_tenant()
        except OUTAGES:
            up.add_metric([], 0)
            yield up
            return
        up.add_metric([], 1)
        by_state = GaugeMetricFamily(
            "bfields_jobs", "Jobs whose record is in an active state, by state.", labels=["state"]
        )
        for state, n in rows.jobs_by_state.items():
            by_state.add_metric([state], n)
        active = GaugeMetricFamily("bfields_jobs_active", "Jobs whose record is queued or running.")
        active.add_metric([], sum(rows.jobs_by_state.values()))
        waiting = GaugeMetricFamily(
            "bfields_jobs_waiting",
            "Jobs waiting in the tenants' fair-share queues, not yet dispatched to a Celery queue "
            "(per tenant where BFIELDS_METRICS_PER_TENANT is on; autoscaling adds this to "
            "bfields_queue_depth; see deploy/keda.yaml).",
            labels=["tenant"] if per_tenant else [],
        )
        if per_tenant:
            for tenant, n in sorted(counts.items()):
                waiting.add_metric([tenant], n)
            if not counts:  # a series even when nothing waits, so sum() in a query is 0, not empty
                waiting.add_metric([""], 0)
        else:
            waiting.add_metric([], sum(counts.values()))
        outbox = GaugeMetricFamily(
            "bfields_callback_outbox_depth", "Callbacks neither delivered nor dropped yet (the outbox)."
        )
        outbox.add_metric([], rows.outbox_open)
        outbox_age = GaugeMetricFamily(
            "bfields_callback_outbox_oldest_age_seconds",
            "Age of the oldest callback neither delivered nor dropped; 0 when none is open.",
        )
        outbox_age.add_metric([], rows.outbox_oldest_age_s)
        leader = GaugeMetricFamily(
            "bfields_control_leader",
            "1 while a control process holds the leader's lease (unexpired), else 0.",
        )
        leader.add_metric([], 1 if rows.leader_held else 0)
        stalled = GaugeMetricFamily(
            "bfields_jobs_stalled",
            "Dispatched, unfinished jobs whose worker's heartbeat is older than the stage lease "
            "(BFIELDS_STAGE_LOCK_TTL_S): recovery requeues them after its grace period.",
        )
        stalled.add_metric([], rows.stalled_jobs)
        yield from (up, by_state, active, waiting, outbox, outbox_age, leader, stalled)

    def _tenant_gate(self, per_tenant: bool) -> Iterator:
        """This process's tenant fairness gate (api/tenant_gate.py): requests in flight, waiting and
        streams open, and the 429s it answered; per tenant only where the operator turned that on."""
        labels = ["tenant"] if per_tenant else []
        load = self.state.tenant_gate.load()
        refused = self.state.tenant_gate.refused
        families = {
            "in_flight": GaugeMetricFamily("bfields_api_tenant_requests_in_flight",
                                           "Tenants' requests this API process serves now.", labels=labels),
            "waiting": GaugeMetricFamily("bfields_api_tenant_requests_waiting",
                                         "Tenants' requests waiting for a slot (BFIELDS_API_TENANT_CONCURRENCY).",
                                         labels=labels),
            "streams": GaugeMetricFamily("bfields_api_tenant_streams_open",
                                         "Tenants' streamed answers open without a request slot.", labels=labels),
        }  # fmt: skip
        refusals = CounterMetricFamily("bfields_api_tenant_refused_total",
                                       "Requests answered 429 because the tenant's queue was full.", labels=labels)  # fmt: skip
        rate = self.state.tenant_gate.rate
        rate_refused = rate.refused if rate is not None else {}
        rate_refusals = CounterMetricFamily("bfields_api_tenant_rate_refused_total",
                                            "Requests answered 429 because the tenant was past its request rate "
                                            "(BFIELDS_API_TENANT_RATE / _BURST).", labels=labels)  # fmt: skip
        if per_tenant:
            for tenant, now in sorted(load.items()):
                for name, family in families.items():
                    family.add_metric([tenant], getattr(now, name))
            for tenant, n in sorted(refused.items()):
                refusals.add_metric([tenant], n)
            for tenant, n in sorted(rate_refused.items()):
                rate_refusals.add_metric([tenant], n)
        else:
            for name, family in families.items():
                family.add_metric([], sum(getattr(now, name) for now in load.values()))
            refusals.add_metric([], sum(refused.values()))
            rate_refusals.add_metric([], sum(rate_refused.values()))
        yield from (*families.values(), refusals, rate_refusals)


def metrics_registry(state: AppState) -> CollectorRegistry:
    registry = CollectorRegistry(auto_describe=False)
    registry.register(ServiceCollector(state))
    return registry


def require_metrics_access(request: Request, state: AppState = Depends(get_state)) -> None:
    """404 where metrics are off (no token, not anonymous); 401 without the metrics token."""
    settings: ServiceSettings = state.settings
    if settings.metrics_anonymous:
        return
    if settings.metrics_token is None:
        raise HTTPException(
            status.HTTP_404_NOT_FOUND,
            "metrics are off: set BFIELDS_METRICS_TOKEN (sent as Authorization: Bearer) or "
            "BFIELDS_METRICS_ANONYMOUS=true",
        )
    scheme, _, presented = request.headers.get("authorization", "").partition(" ")
    expected = settings.metrics_token.get_secret_value()
    if scheme.lower() != "bearer" or not hmac.compare_digest(presented.strip().encode(), expected.encode()):
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            "GET /metrics needs the metrics token as Authorization: Bearer <token> (BFIELDS_METRICS_TOKEN; "
            "an API key does not open it)",
            headers={"WWW-Authenticate": "Bearer"},
        )


@router.get(
    "/metrics",
    summary="Prometheus metrics (Authorization: Bearer <BFIELDS_METRICS_TOKEN>)",
    response_class=Response,
    dependencies=[Depends(require_metrics_access)],
    responses={401: {"description": "Without the metrics token"}, 404: {"description": "Metrics are off"}},
)
def metrics(state: AppState = Depends(get_state)) -> Response:
    return Response(generate_latest(state.metrics_registry), media_type=CONTENT_TYPE_LATEST)
