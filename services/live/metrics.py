"""Job and stage metrics that outlive worker processes: histograms kept in Redis hashes.

Workers come and go (and are killed on purpose), so per-process prometheus counters would be
lost or need a push gateway. Instead each observation increments a bucket counter in a Redis hash;
the API's `/metrics` turns those hashes into Prometheus histograms. One HINCRBY per bucket per
stage is negligible next to a stage that runs for seconds to hours.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import redis

from bayesian_fields_service.live import redis_keys
from bayesian_fields_service.live.broker import queue_length
from bayesian_fields_service.live.redis_text import text

#: Upper bounds (seconds) of the duration histograms.
BUCKETS: tuple[float, ...] = (1, 5, 15, 30, 60, 120, 300, 600, 1800, 3600, 7200, 14400)

STAGE_KEY = redis_keys.STAGE_HISTOGRAM
JOB_KEY = redis_keys.JOB_HISTOGRAM


def _observe(client: redis.Redis, key: str, seconds: float) -> None:
    pipe = client.pipeline()
    pipe.hincrbyfloat(key, "sum", seconds)
    pipe.hincrby(key, "count", 1)
    for bound in BUCKETS:
        if seconds <= bound:
            pipe.hincrby(key, f"le_{bound:g}", 1)
    pipe.execute()


def observe_stage(client: redis.Redis, stage: str, seconds: float) -> None:
    _observe(client, STAGE_KEY.format(stage=stage), seconds)


def observe_job(client: redis.Redis, outcome: str, seconds: float) -> None:
    _observe(client, JOB_KEY.format(outcome=outcome), seconds)


#: A stored histogram as Prometheus takes it: (cumulative buckets incl. +Inf, sum, count).
Histogram = tuple[list[tuple[str, float]], float, float]


def read_histogram(client: redis.Redis, key: str) -> Histogram | None:
    """(cumulative buckets incl. +Inf, sum, count) of one stored histogram, or None."""
    raw = client.hgetall(key)
    if not raw:
        return None
    data = {text(k): float(v) for k, v in raw.items()}
    count = data.get("count", 0.0)
    buckets = [(f"{b:g}", data.get(f"le_{b:g}", 0.0)) for b in BUCKETS] + [("+Inf", count)]
    return buckets, data.get("sum", 0.0), count


QUEUE_WAIT_KEY = redis_keys.QUEUE_WAIT_HISTOGRAM


def observe_queue_wait(client: redis.Redis, tenant: str, seconds: float) -> None:
    """Seconds a job waited from submission to its dispatch to a worker queue (per tenant)."""
    _observe(client, QUEUE_WAIT_KEY.format(tenant=tenant), seconds)


def queue_wait_tenants(client: redis.Redis) -> list[str]:
    prefix = QUEUE_WAIT_KEY.format(tenant="")
    return sorted(text(k)[len(prefix) :] for k in client.scan_iter(match=prefix + "*", count=200))


@dataclass(frozen=True)
class LiveReading:
    """What `/metrics` reads of the live state at one scrape: each queue's depth, and the stored
    histograms of stages and jobs (by outcome) and of the tenants' queue waits (by tenant), each
    only where one was observed."""

    queue_depths: dict[str, int]
    stages: dict[str, Histogram]
    jobs: dict[str, Histogram]
    queue_waits: dict[str, Histogram]


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
        except redis.RedisError:
            return None
        return LiveReading(depths, by_stage, by_outcome, waits)
