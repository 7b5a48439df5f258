"""A per-tenant request rate on one API process: a token bucket per tenant.

Why a rate as well as the concurrency bound (tenant_gate.py): the bound keeps one tenant's requests
from queueing ahead of another's, but a tenant that sends requests back to back from many threads
still keeps its `limit` slots busy all the time, and the other tenants' requests share the
interpreter and the CPU with them: on the shared 2-core machine another tenant's p99 was 3x its
idle value at the default bound (issue 41, item 5). Bounding the rate bounds the CPU a tenant can
take, whatever its parallelism, which is what keeps the others' latency near idle.

A bucket holds at most `burst` tokens and refills at `rate` per second; each ``/v1/`` request of
the tenant takes one. A request that finds none is not refused at once: it reserves the next token
and waits for it on the event loop (holding nothing but its connection), up to `max_delay_s`; so a
tenant's requests past its rate are spread out evenly, `1 / rate` apart, instead of arriving in
bursts whenever a refusal's Retry-After runs out (which would bring back the very contention the
rate is for, for part of every second). Only a request that would wait longer is answered 429,
with ``Retry-After`` (whole seconds until it would be let in without waiting that long) and the
``RateLimit`` / ``RateLimit-Policy`` headers of the IETF httpapi draft, before any route runs.
`burst` lets a client's natural bursts through at once (a ``bfields fetch`` of a result is a dozen
requests). A rate of 0 turns the bound off. Runs on the event loop only, so no lock.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

#: The policy's name in the RateLimit headers (one policy: requests per tenant per API process).
POLICY = "requests"


@dataclass
class _Bucket:
    tokens: float
    at: float  # monotonic time of the last refill


@dataclass(frozen=True)
class RateVerdict:
    """What a request's take from its tenant's bucket says: let in or not, and the headers."""

    allowed: bool
    delay_s: float  # when allowed: how long the request waits for its reserved token (0: none)
    remaining: int  # whole tokens left after this request
    retry_after_s: int  # when refused: whole seconds until a request would wait at most max_delay_s
    full_in_s: int  # whole seconds until the bucket is full again

    def headers(self, policy: str) -> dict[str, str]:
        """``RateLimit-Policy`` and ``RateLimit`` (draft-ietf-httpapi-ratelimit-headers), plus
        ``Retry-After`` on a refusal."""
        out = {"RateLimit-Policy": policy, "RateLimit": f'"{POLICY}";r={self.remaining};t={self.full_in_s}'}
        if not self.allowed:
            out["Retry-After"] = str(self.retry_after_s)
        return out


class TenantRate:
    """Each tenant's token bucket on this process (module text)."""

    def __init__(
        self, rate: float, burst: int, max_delay_s: float = 1.0, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.rate = rate
        self.burst = burst
        self.max_delay_s = max_delay_s
        self.clock = clock
        self._buckets: dict[str, _Bucket] = {}
        self.refused: dict[str, int] = {}  # 429s of the rate per tenant since the process started

    @property
    def enabled(self) -> bool:
        return self.rate > 0

    @property
    def policy(self) -> str:
        """The ``RateLimit-Policy`` value: the sustained rate as `q` requests per `w` seconds (one
        second, or the whole seconds one token takes where the rate is below one a second)."""
        window = max(1, math.ceil(1.0 / self.rate)) if self.enabled else 1
        return f'"{POLICY}";q={max(1, round(self.rate * window))};w={window}'

    def take(self, tenant: str) -> RateVerdict:
        """Take (or reserve) one token of `tenant`'s bucket, refilled for the time since its last
        take. Tokens below zero are reservations of requests now waiting for their turn."""
        now = self.clock()
        b = self._buckets.get(tenant)
        if b is None:
            b = self._buckets[tenant] = _Bucket(float(self.burst), now)
        else:
            b.tokens = min(float(self.burst), b.tokens + (now - b.at) * self.rate)
            b.at = now
        delay = max(0.0, (1.0 - b.tokens) / self.rate)
        allowed = delay <= self.max_delay_s
        if allowed:
            b.tokens -= 1.0
        else:
            self.refused[tenant] = self.refused.get(tenant, 0) + 1
        retry = 0 if allowed else max(1, math.ceil(delay - self.max_delay_s))
        full_in = math.ceil((self.burst - b.tokens) / self.rate)
        self._forget_full(now)
        return RateVerdict(allowed, delay if allowed else 0.0, max(0, int(b.tokens)), retry, full_in)

    def _forget_full(self, now: float) -> None:
        """Drop the buckets that have refilled completely (they carry no state), so the table stays
        as small as the set of recently busy tenants."""
        if len(self._buckets) <= 64:
            return
        for name, b in list(self._buckets.items()):
            if b.tokens + (now - b.at) * self.rate >= self.burst:
                del self._buckets[name]
