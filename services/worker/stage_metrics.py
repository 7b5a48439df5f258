"""The worker's observations for `/metrics` beyond a stage's duration: how long its message
waited in the queue, and what it used (CPU and GPU seconds, peak GPU memory).

Why never raising: these are progress-grade numbers kept in Redis (`live.metrics`); a Redis
outage must not fail or retry a stage over a metric, so a lost observation is logged and dropped.
"""

from __future__ import annotations

import logging
from typing import Any

import redis

from bayesian_fields_service.live.metrics import observe_stage_queue_wait, observe_stage_resources
from bayesian_fields_service.live.stage_wait import waited_s
from bayesian_fields_service.worker.accounting import StageMeter

log = logging.getLogger(__name__)


def observe_queue_wait(client: redis.Redis, stage: str, request: Any) -> None:
    """The delivery's wait from its publication to now (its start on this worker), where stamped."""
    waited = waited_s(request)
    if waited is None:
        return
    try:
        observe_stage_queue_wait(client, stage, waited)
    except redis.RedisError as exc:
        log.warning("queue wait of a %s message not recorded (Redis: %s)", stage, exc)


def observe_resources(client: redis.Redis, stage: str, meter: StageMeter) -> None:
    """One ended stage execution's CPU / GPU seconds and peak GPU memory (0 on a CPU worker)."""
    try:
        observe_stage_resources(
            client, stage, cpu_s=meter.cpu_s, gpu_s=meter.gpu_s, gpu_peak_bytes=meter.gpu_peak_bytes
        )
    except redis.RedisError as exc:
        log.warning("resources of stage %s not recorded (Redis: %s)", stage, exc)
