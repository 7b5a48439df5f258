"""`LiveMetrics`, what `GET /metrics` reads of the live state, on a real Redis: each queue's depth
(every priority list of it), the histograms observed (and only those), every tenant's queue wait;
and None, not an error, when Redis does not answer (the scrape then leaves these series out)."""

from __future__ import annotations

import redis

from bayesian_fields_service.live.broker import PRIORITY_SUFFIXES
from bayesian_fields_service.live.metrics import (
    LiveMetrics,
    observe_job,
    observe_queue_wait,
    observe_stage,
)
from tests.integration.fixtures.processes import free_port
from tests.integration.fixtures.redis_server import RedisServer


def test_a_reading_holds_the_depths_and_the_histograms_observed(private_redis: RedisServer) -> None:
    client = redis.Redis.from_url(private_redis.url())
    client.rpush("gpu", "m1", "m2")
    client.rpush("gpu" + PRIORITY_SUFFIXES[1], "m3")  # a message of another priority counts too
    observe_stage(client, "fuse", 3.0)
    observe_stage(client, "fuse", 20.0)
    observe_job(client, "failed", 7.0)
    observe_queue_wait(client, "acme", 0.5)
    reading = LiveMetrics(client).read(["gpu", "cpu"], ["perceive", "fuse"], ["succeeded", "failed"])
    assert reading is not None
    assert reading.queue_depths == {"gpu": 3, "cpu": 0}
    assert set(reading.stages) == {"fuse"} and set(reading.jobs) == {"failed"}  # only what was observed
    buckets, total, count = reading.stages["fuse"]
    assert (total, count) == (23.0, 2.0)
    assert dict(buckets)["5"] == 1.0 and dict(buckets)["30"] == 2.0 and buckets[-1] == ("+Inf", 2.0)
    assert set(reading.queue_waits) == {"acme"} and reading.queue_waits["acme"][2] == 1.0


def test_no_reading_when_redis_does_not_answer() -> None:
    gone = redis.Redis(port=free_port(), socket_connect_timeout=0.5, socket_timeout=0.5)
    assert LiveMetrics(gone).read(["gpu"], ["fuse"], ["failed"]) is None
