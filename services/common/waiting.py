"""Jobs waiting for a worker, per tenant: the number autoscaling needs besides the Celery queues.

The fair-share dispatcher (issue 20, item 2; another branch) keeps each tenant's waiting jobs in
Redis, in one key per tenant named ``bf:fair:waiting:<tenant>`` (a sorted set or a list) and
releases them into the Celery queues a few at a time, so the Celery queue lengths alone no longer
show the backlog. This module is the one place that reads those keys; `/metrics` exports the
result as ``bfields_jobs_waiting{tenant}`` and `deploy/keda.yaml` scales the workers on
``sum(bfields_jobs_waiting) + bfields_queue_depth``. Assumption (to be kept in step with the
dispatcher): the key pattern above, one member per waiting job. Before the dispatcher exists no such
key is there and every tenant counts 0 (the Celery queues then hold the whole backlog).
"""

from __future__ import annotations

import redis

from bayesian_fields_service.common.redis_text import text

WAITING_PREFIX = "bf:fair:waiting:"


def waiting_by_tenant(client: redis.Redis) -> dict[str, int]:
    """{tenant: jobs waiting} over every ``bf:fair:waiting:<tenant>`` key (SCAN, no KEYS)."""
    keys = [text(k) for k in client.scan_iter(match=WAITING_PREFIX + "*", count=500)]
    if not keys:
        return {}
    pipe = client.pipeline()
    for key in keys:
        pipe.type(key)
    kinds = [text(k) for k in pipe.execute()]
    pipe = client.pipeline()
    counted = []
    for key, kind in zip(keys, kinds, strict=True):
        if kind == "zset":
            pipe.zcard(key)
        elif kind == "list":
            pipe.llen(key)
        elif kind == "set":
            pipe.scard(key)
        else:
            continue
        counted.append(key[len(WAITING_PREFIX) :])
    return dict(zip(counted, (int(n) for n in pipe.execute()), strict=True))
