"""Job and stage metrics that outlive worker processes: histograms kept in Redis hashes.

Workers come and go (and are killed on purpose), so per-process prometheus counters would be
lost or need a push gateway. Instead each observation increments a bucket counter in a Redis hash;
the API's `/metrics` turns those hashes into Prometheus histograms. One HINCRBY per bucket per
stage is negligible next to a stage that runs for seconds to hours.
"""

from __future__ import annotations

import redis

from bayesian_fields_service.live import redis_keys
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


def read_histogram(client: redis.Redis, key: str) -> tuple[list[tuple[str, float]], float, float] | None:
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
