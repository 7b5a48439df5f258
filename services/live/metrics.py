"""Job and stage metrics that outlive worker processes: histograms kept in Redis hashes.

Workers come and go (and are killed on purpose), so per-process prometheus counters would be
lost or need a push gateway. Instead each observation increments a bucket counter in a Redis hash;
the API's `/metrics` turns those hashes into Prometheus histograms. One HINCRBY per bucket per
stage is negligible next to a stage that runs for seconds to hours.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import redis

from bayesian_fields_service.live import redis_keys
from bayesian_fields_service.live.broker import queue_length
from bayesian_fields_service.live.redis_text import text

#: Upper bounds (seconds) of the duration histograms.
BUCKETS: tuple[float, ...] = (1, 5, 15, 30, 60, 120, 300, 600, 1800, 3600, 7200, 14400)
#: Upper bounds (seconds) of a stage message's wait in its queue: a free worker takes one within
#: a fraction of a second, a saturated pool makes it wait minutes to hours.
WAIT_BUCKETS: tuple[float, ...] = (0.1, 0.5, 1, 5, 15, 30, 60, 120, 300, 600, 1800, 3600, 7200)
#: Upper bounds (bytes) of a stage's peak GPU memory: 0 (a CPU worker's stages, so that
#: ``histogram_quantile`` answers 0 for them rather than a fraction of the next bound), then 256 MiB
#: to 128 GiB, doubling.
MEMORY_BUCKETS: tuple[float, ...] = (0.0, *(float(2**n) for n in range(28, 38)))

STAGE_KEY = redis_keys.STAGE_HISTOGRAM
JOB_KEY = redis_keys.JOB_HISTOGRAM


def _bound(bound: float) -> str:
    """A bucket's bound as its field name and ``le`` label: ``%g`` (the stored fields of the
    duration histograms are named so), or the exact ``repr`` where ``%g`` would round it."""
    short = f"{bound:g}"
    return short if float(short) == bound else repr(float(bound))


def _observe(client: redis.Redis, key: str, value: float, buckets: tuple[float, ...] = BUCKETS) -> None:
    pipe = client.pipeline()
    pipe.hincrbyfloat(key, "sum", value)
    pipe.hincrby(key, "count", 1)
    for bound in buckets:
        if value <= bound:
            pipe.hincrby(key, f"le_{_bound(bound)}", 1)
    pipe.execute()


def observe_stage(client: redis.Redis, stage: str, seconds: float) -> None:
    _observe(client, STAGE_KEY.format(stage=stage), seconds)


def observe_job(client: redis.Redis, outcome: str, seconds: float) -> None:
    _observe(client, JOB_KEY.format(outcome=outcome), seconds)


#: A stored histogram as Prometheus takes it: (cumulative buckets incl. +Inf, sum, count).
Histogram = tuple[list[tuple[str, float]], float, float]


def read_histogram(client: redis.Redis, key: str, bounds: tuple[float, ...] = BUCKETS) -> Histogram | None:
    """(cumulative buckets incl. +Inf, sum, count) of one stored histogram, or None."""
    raw = client.hgetall(key)
    if not raw:
        return None
    data = {text(k): float(v) for k, v in raw.items()}
    count = data.get("count", 0.0)
    buckets = [(_bound(b), data.get(f"le_{_bound(b)}", 0.0)) for b in bounds] + [("+Inf", count)]
    return buckets, data.get("sum", 0.0), count


QUEUE_WAIT_KEY = redis_keys.QUEUE_WAIT_HISTOGRAM


def observe_queue_wait(client: redis.Redis, tenant: str, seconds: float) -> None:
    """Seconds a job waited from submission to its dispatch to a worker queue (per tenant)."""
    _observe(client, QUEUE_WAIT_KEY.format(tenant=tenant), seconds)


STAGE_QUEUE_WAIT_KEY = redis_keys.STAGE_QUEUE_WAIT_HISTOGRAM
STAGE_GPU_MEMORY_KEY = redis_keys.STAGE_GPU_MEMORY_HISTOGRAM
STAGE_USAGE_KEY = redis_keys.STAGE_USAGE


def observe_stage_queue_wait(client: redis.Redis, stage: str, seconds: float) -> None:
    """Seconds a stage's message waited from its publication (the dispatcher's send, or the end
    of the previous stage of its chain, or a retry's due time) until a worker started it."""
    _observe(client, STAGE_QUEUE_WAIT_KEY.format(stage=stage), max(0.0, seconds), WAIT_BUCKETS)


def observe_stage_resources(
    client: redis.Redis, stage: str, *, cpu_s: float, gpu_s: float, gpu_peak_bytes: float
) -> None:
    """One finished stage execution's CPU and GPU seconds (added to the stage's counters) and its
    peak GPU memory (a histogram; 0 on a CPU worker)."""
    key = STAGE_USAGE_KEY.format(stage=stage)
    pipe = client.pipeline()
    pipe.hincrbyfloat(key, "cpu_s", cpu_s)
    pipe.hincrbyfloat(key, "gpu_s", gpu_s)
    pipe.execute()
    _observe(client, STAGE_GPU_MEMORY_KEY.format(stage=stage), gpu_peak_bytes, MEMORY_BUCKETS)


def read_stage_usage(client: redis.Redis, stage: str) -> dict[str, float]:
    """{'cpu_s': ..., 'gpu_s': ...} of one stage's executions so far (0 where none)."""
    raw = {text(k): float(v) for k, v in client.hgetall(STAGE_USAGE_KEY.format(stage=stage)).items()}
    return {"cpu_s": raw.get("cpu_s", 0.0), "gpu_s": raw.get("gpu_s", 0.0)}


def queue_wait_tenants(client: redis.Redis) -> list[str]:
    prefix = QUEUE_WAIT_KEY.format(tenant="")
    return sorted(text(k)[len(prefix) :] for k in client.scan_iter(match=prefix + "*", count=200))


@dataclass(frozen=True)
class LiveReading:
    """What `/metrics` reads of the live state at one scrape: each queue's depth, and the stored
    histograms of stages and jobs (by outcome) and of the tenants' queue waits (by tenant), each
    only where one was observed; per stage, its messages' queue waits and peak GPU memory (where
    observed) and its CPU / GPU seconds (every stage, 0 before the first)."""

    queue_depths: dict[str, int]
    stages: dict[str, Histogram]
    jobs: dict[str, Histogram]
    queue_waits: dict[str, Histogram]
    stage_queue_waits: dict[str, Histogram] = field(default_factory=dict)
    stage_gpu_memory: dict[str, Histogram] = field(default_factory=dict)
    stage_usage: dict[str, dict[str, float]] = field(default_factory=dict)


class LiveMetrics:
    """The live state's metrics as the API's `/metrics` reads them (the broker's queue depths and
    the histograms above). Why an object: the routes reach no Redis client (issue 43); the API's
    state holds this one, over the request path's client."""

    def __init__(self, client: redis.Redis) -> None:
        self._client = client

    def read(
        self, queues: Iterable[str], stages: Iterable[str], outcomes: Iterable[str]
    ) -> LiveReading | None:
        """One reading of `queues`' depths and the histograms of `stages`, job `outcomes` and every
        tenant's queue wait; None when Redis does not answer (the scrape then leaves these out:
        losing Redis loses nothing but progress, and these are progress)."""
        client = self._client
        stages = list(stages)
        try:
            depths = {queue: queue_length(client, queue) for queue in queues}
            by_stage = {
                s: h for s in stages if (h := read_histogram(client, STAGE_KEY.format(stage=s))) is not None
            }
            by_outcome = {
                o: h for o in outcomes if (h := read_histogram(client, JOB_KEY.format(outcome=o))) is not None
            }
            waits = {
                t: h
                for t in queue_wait_tenants(client)
                if (h := read_histogram(client, QUEUE_WAIT_KEY.format(tenant=t))) is not None
            }
            stage_waits = {
                s: h
                for s in stages
                if (h := read_histogram(client, STAGE_QUEUE_WAIT_KEY.format(stage=s), WAIT_BUCKETS))
                is not None
            }
            memory = {
                s: h
                for s in stages
                if (h := read_histogram(client, STAGE_GPU_MEMORY_KEY.format(stage=s), MEMORY_BUCKETS))
                is not None
            }
            usage = {s: read_stage_usage(client, s) for s in stages}
        except redis.RedisError:
            return None
        return LiveReading(depths, by_stage, by_outcome, waits, stage_waits, memory, usage)
