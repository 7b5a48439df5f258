"""A per-tenant bound on the requests one API process serves at once, so no tenant starves another.

Why: one API process serves every tenant from one event loop, one thread pool (the sync routes) and
one records pool. A tenant polling its batch from 20 threads back to back kept ~20 of its requests
in flight, and another tenant's request queued behind all of them: its p99 went 15x (issue 41,
item 5). So `TenantFairness`, a pure ASGI middleware and the outermost of the app's, resolves the
tenant from the API key before any route runs (`security.auth.key_in_headers`, the same headers
and rules as the routes' authentication) and lets at most `limit` of that tenant's requests in at
once. The rest wait in the tenant's own first-in-first-out queue, so another tenant's request never
waits behind them; past `queue_max` waiting, the request is answered 429 with ``Retry-After`` at
once, before it costs anything more (an `api.problems` body, with the ``"concurrency"`` policy's
RateLimit fields of `api.ratelimit`).

What is not limited: paths outside ``/v1/`` (health, metrics, /ui pages and their assets, the API
docs) and a request with no key or an unknown one (it is not any tenant's; the route answers 401).

Streams (SSE ``/events``, the CSV / JSON Lines answer exports, ``result.zip``): a response whose
first body chunk says more is coming gives its request slot back and counts among the tenant's
open streams instead, up to `streams_max`; so a dashboard's event stream does not hold one of the
tenant's request slots for an hour. A stream opened past `streams_max` keeps its request slot until
it ends, so a tenant's streams past that bound hold up only that tenant's own requests, and the
work one tenant has going at once stays bounded by ``limit + streams_max``.

The bound is per process: with uvicorn workers or several replicas, each process bounds its own.
Everything here runs on the event loop, so no lock is needed.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from starlette.datastructures import MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from bayesian_fields_service.api.problems import problem_response
from bayesian_fields_service.api.ratelimit import CONCURRENCY_POLICY, add_policies, policy_headers
from bayesian_fields_service.api.tenant_rate import RateVerdict, TenantRate
from bayesian_fields_service.security.auth import RESOLVED_TENANT

#: Only these paths are a tenant's requests (every route that takes an API key lives under it).
LIMITED_PREFIX = "/v1/"


@dataclass
class _Tenant:
    """One tenant's slots on this process: requests in flight, requests waiting, open streams."""

    in_flight: int = 0
    streams: int = 0
    waiters: deque[asyncio.Future[None]] = field(default_factory=deque)

    @property
    def idle(self) -> bool:
        return self.in_flight == 0 and self.streams == 0 and not self.waiters


@dataclass(frozen=True)
class TenantLoad:
    """What `TenantGate.load` reports of one tenant (the metrics' gauges)."""

    in_flight: int
    waiting: int
    streams: int


class TenantGate:
    """The slots and FIFO queues of every tenant with a request on this process."""

    def __init__(self, limit: int, queue_max: int, streams_max: int, rate: TenantRate | None = None) -> None:
        self.limit = limit
        self.queue_max = queue_max
        self.streams_max = streams_max
        self.rate = rate  # the tenants' request rate (tenant_rate.py), checked before a slot is taken
        self._tenants: dict[str, _Tenant] = {}
        self.refused: dict[str, int] = {}  # 429s per tenant since the process started

    async def enter(self, tenant: str) -> bool:
        """Take one of `tenant`'s slots, waiting in its queue for one; False: the queue is full."""
        t = self._tenants.setdefault(tenant, _Tenant())
        if t.in_flight < self.limit and not t.waiters:
            t.in_flight += 1
            return True
        if len(t.waiters) >= self.queue_max:
            self.refused[tenant] = self.refused.get(tenant, 0) + 1
            if t.idle:
                del self._tenants[tenant]
            return False
        turn: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        t.waiters.append(turn)
        try:
            await turn
        except asyncio.CancelledError:
            if turn.done() and not turn.cancelled():
                self.leave(tenant)  # the slot was handed over as the request was cancelled
            elif turn in t.waiters:
                t.waiters.remove(turn)
                self._forget_if_idle(tenant)
            raise
        return True  # `leave` handed its slot over: in_flight already counts this request

    def leave(self, tenant: str) -> None:
        """Give a slot back: to the tenant's first waiting request, else free."""
        t = self._tenants[tenant]
        while t.waiters:
            turn = t.waiters.popleft()
            if not turn.done():
                turn.set_result(None)
                return
        t.in_flight -= 1
        self._forget_if_idle(tenant)

    def stream_started(self, tenant: str) -> bool:
        """A response of `tenant` turned out to stream: True if it moved from its request slot to
        the tenant's open streams (its slot is free), False if the stream bound is reached (it
        keeps its request slot)."""
        t = self._tenants[tenant]
        if t.streams >= self.streams_max:
            return False
        t.streams += 1
        self.leave(tenant)
        return True

    def stream_ended(self, tenant: str) -> None:
        self._tenants[tenant].streams -= 1
        self._forget_if_idle(tenant)

    def load(self) -> dict[str, TenantLoad]:
        """Each tenant's requests in flight, waiting and open streams, now."""
        return {name: TenantLoad(t.in_flight, len(t.waiters), t.streams) for name, t in self._tenants.items()}

    def _forget_if_idle(self, tenant: str) -> None:
        t = self._tenants.get(tenant)
        if t is not None and t.idle:
            del self._tenants[tenant]


class TenantFairness:
    """Pure ASGI middleware: the tenant's slot around each of its ``/v1/`` requests (module text)."""

    def __init__(
        self,
        app: ASGIApp,
        gate: TenantGate,
        tenant_of: Callable[[Scope], str | None],
        retry_after_s: int,
    ) -> None:
        self.app = app
        self.gate = gate
        self.tenant_of = tenant_of
        self.retry_after_s = retry_after_s
        self.rate = gate.rate

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or not scope["path"].startswith(LIMITED_PREFIX):
            await self.app(scope, receive, send)
            return
        tenant = self.tenant_of(scope)
        if tenant is None:  # no key or an unknown one: not a tenant's request; the route says 401
            await self.app(scope, receive, send)
            return
        scope.setdefault("state", {})[RESOLVED_TENANT] = tenant  # the routes' auth reads it (auth.py)
        verdict = self.rate.take(tenant) if self.rate is not None and self.rate.enabled else None
        if verdict is not None and not verdict.allowed:
            await self._refuse_rate(verdict, scope, receive, send)
            return
        if verdict is not None and verdict.delay_s > 0:
            await asyncio.sleep(verdict.delay_s)  # its reserved turn (tenant_rate.py says why)
        if not await self.gate.enter(tenant):
            await self._refuse(scope, receive, send)
            return
        holds_slot = True
        streaming = False

        async def counted_send(message: Message) -> None:
            nonlocal holds_slot, streaming
            if message["type"] == "http.response.start" and verdict is not None and self.rate is not None:
                add_policies(MutableHeaders(scope=message), verdict.headers(self.rate.policy))
            if message["type"] == "http.response.body" and message.get("more_body") and not streaming:
                streaming = True
                if self.gate.stream_started(tenant):
                    holds_slot = False
            await send(message)

        try:
            await self.app(scope, receive, counted_send)
        finally:
            if holds_slot:
                self.gate.leave(tenant)
            else:
                self.gate.stream_ended(tenant)

    async def _refuse_rate(self, verdict: RateVerdict, scope: Scope, receive: Receive, send: Send) -> None:
        assert self.rate is not None
        detail = (
            f"too many requests of this tenant: more than {self.rate.rate:g} per second sustained (and "
            f"{self.rate.burst} at once) on this API process, with requests already waiting "
            f"{self.rate.max_delay_s:g} s for their turn (BFIELDS_API_TENANT_RATE, BFIELDS_API_TENANT_BURST); "
            f"retry after {verdict.retry_after_s} s, or poll less often (a batch's counts: "
            f"GET /v1/batches/{{id}}; its answers: GET /v1/batches/{{id}}/answers)"
        )
        answer = problem_response(
            "too-many-requests", detail, scope["path"], headers=verdict.headers(self.rate.policy)
        )
        await answer(scope, receive, send)

    async def _refuse(self, scope: Scope, receive: Receive, send: Send) -> None:
        g = self.gate
        detail = (
            f"too many requests of this tenant at once: {g.limit} in flight and {g.queue_max} waiting on "
            f"this API process (BFIELDS_API_TENANT_CONCURRENCY, BFIELDS_API_TENANT_QUEUE); retry after "
            f"{self.retry_after_s} s or send fewer requests in parallel"
        )
        bound = policy_headers(CONCURRENCY_POLICY, g.limit + g.queue_max, 0, reset_s=self.retry_after_s,
                               unit="concurrent-requests")  # fmt: skip
        answer = problem_response(
            "too-many-at-once",
            detail,
            scope["path"],
            headers={"Retry-After": str(self.retry_after_s), **bound},
        )
        await answer(scope, receive, send)
