"""The workers' `Flight` (`bayesian_fields_core.job.flight`): a Redis lock per cache fill.

Key: ``bf:flight:<tenant>:<kind>:<hash of the cache keys>``; the cache keys carry the scene's cache
root, the models' fingerprint and the frames' content digests, so jobs on the same scene content
and model profile meet on one lock, whatever their task lists. The holder renews the lock from a
heartbeat thread every third of `flight_lock_ttl_s`; a SIGKILLed holder stops renewing and its lock
expires, so a waiter takes it over within the TTL. A waiter polls (`flight_poll_s`), calls the
stage's cancel check while it waits, and past `flight_wait_timeout_s` stops waiting and computes
itself (a stuck but alive holder costs duplicate work, never a hung job).
"""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import socket
import time
from collections.abc import Callable, Iterator

import redis

from bayesian_fields_service.live import redis_keys
from bayesian_fields_service.live.heartbeat_lock import HeartbeatLock

log = logging.getLogger(__name__)


def flight_redis_key(tenant: str, key: str) -> str:
    return redis_keys.flight_lock(tenant, key)


class RedisFlight:
    """Holds flight keys of one tenant in Redis (one object per job)."""

    def __init__(
        self,
        client: redis.Redis,
        tenant: str,
        *,
        ttl_s: float,
        wait_timeout_s: float,
        poll_s: float = 0.25,
        on_waited: Callable[[str, float], None] | None = None,
    ) -> None:
        self.client = client
        self.tenant = tenant
        self.ttl_ms = int(ttl_s * 1000)
        self.wait_timeout_s = wait_timeout_s
        self.poll_s = poll_s
        self.on_waited = on_waited

    @contextlib.contextmanager
    def hold(self, key: str, *, on_wait: Callable[[], None]) -> Iterator[None]:
        token = f"{socket.gethostname()}:{os.getpid()}:{secrets.token_hex(8)}"
        lock = HeartbeatLock(
            self.client, flight_redis_key(self.tenant, key), token, self.ttl_ms / 1000, beats=3
        )
        start = time.monotonic()
        held = True
        while not lock.acquire():
            on_wait()  # a cancelled job stops waiting here
            if time.monotonic() - start > self.wait_timeout_s:
                log.warning(
                    "flight %s: still held after %.0f s; computing without it", key, self.wait_timeout_s
                )
                held = False
                break
            time.sleep(self.poll_s)
        waited = time.monotonic() - start
        if waited > self.poll_s / 2:
            log.info("flight %s: waited %.1f s for another job filling the cache", key, waited)
            if self.on_waited is not None:
                self.on_waited(key, waited)
        try:
            yield
        finally:
            if held:
                lock.release()
