"""Named points where an integration test can hold a request, to force one interleaving of a race.

Why: the races between `complete`, `delete` and job submission are decided by a few storage
calls; hoping that threads hit them in the right order proves little. With
BFIELDS_TEST_PAUSE_POINTS on, a route calls `pause(name, scene_id)` between its steps; when a
test has armed that point (Redis key ``bf:test:pause:<name>`` holding the scene id), the request
says it arrived (``bf:test:reached:<name>:<scene>``) and waits until the test releases it
(``bf:test:resume:<name>:<scene>``) or `PAUSE_LIMIT_S` passes. Off (the default), it is a no-op
that touches nothing.
"""

from __future__ import annotations

import time

import redis

from bayesian_fields_service.live import redis_keys
from bayesian_fields_service.live.redis_text import text

#: The longest a request ever waits at a point (a test that died must not hang the API).
PAUSE_LIMIT_S = 30.0


def pause(client: redis.Redis, enabled: bool, name: str, scene_id: str) -> None:
    """Wait at point `name` if a test armed it for `scene_id` (only when `enabled`)."""
    if not enabled:
        return
    armed = client.get(redis_keys.pause_armed(name))
    if armed is None or text(armed) != scene_id:
        return
    client.set(redis_keys.pause_reached(name, scene_id), b"1", ex=120)
    resume = redis_keys.pause_resume(name, scene_id)
    deadline = time.monotonic() + PAUSE_LIMIT_S
    while time.monotonic() < deadline and not client.exists(resume):
        time.sleep(0.02)
    client.delete(resume)
