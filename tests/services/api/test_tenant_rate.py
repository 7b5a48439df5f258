"""The per-tenant request rate (services/api/tenant_rate.py; issue 41, item 5): the token bucket's
rules on a clock the test turns, then on a real uvicorn: a tenant past its burst is answered 429 with
Retry-After and the RateLimit headers at once, while another tenant is served; its requests are let
in again once the bucket has refilled; a request with no key is no tenant's.

The HTTP test depends on the machine's speed in one direction only: the burst is sent far faster
than the bucket refills (RATE tokens a second), so the refusal must come within it."""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest

from bayesian_fields_service.api.tenant_rate import TenantRate
from tests.integration.fixtures.services import ApiServer
from tests.services.support.lone_api import lone_api
from tests.services.support.problems import assert_problem

RATE = 0.5  # tokens a second: one request every 2 s sustained
BURST = 6
DELAY_S = 3.0  # a request past the burst waits up to this for its turn


class _Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_bucket_lets_its_burst_through_then_spaces_requests_then_refuses() -> None:
    clock = _Clock()
    rate = TenantRate(rate=2.0, burst=3, max_delay_s=1.0, clock=clock)
    got = [rate.take("a") for _ in range(6)]
    # the burst at once; then each request reserves the next token, 1 / rate apart, while that
    # wait is at most max_delay_s; past it: refused, counted, told when to come back
    assert [v.allowed for v in got] == [True] * 5 + [False]
    assert [v.delay_s for v in got] == [0.0, 0.0, 0.0, 0.5, 1.0, 0.0]
    assert [v.remaining for v in got] == [2, 1, 0, 0, 0, 0]
    assert got[5].retry_after_s == 1 and got[5].headers(rate.policy)["Retry-After"] == "1"
    assert "Retry-After" not in got[4].headers(rate.policy)
    assert rate.refused == {"a": 1}
    assert rate.take("b").delay_s == 0.0  # another tenant has a bucket of its own
    clock.now += 1.0  # the two reservations are served: the bucket is empty, not negative
    assert rate.take("a").delay_s == 0.5
    clock.now += 60.0  # refilled to the burst, never past it
    assert [rate.take("a").delay_s for _ in range(4)] == [0.0, 0.0, 0.0, 0.5]


def test_the_headers_follow_the_draft_and_retry_after_rounds_up() -> None:
    clock = _Clock()
    rate = TenantRate(rate=0.25, burst=2, max_delay_s=0.0, clock=clock)  # a token every 4 s, no waiting
    first = rate.take("a")
    assert rate.policy == '"requests";q=1;w=4'
    assert TenantRate(rate=50.0, burst=20).policy == '"requests";q=50;w=1'
    assert first.headers(rate.policy) == {"RateLimit-Policy": '"requests";q=1;w=4',
                                          "RateLimit": '"requests";r=1;t=4'}  # fmt: skip
    rate.take("a")
    clock.now += 1.0  # a quarter of a token back: three more seconds to the next one
    refused = rate.take("a")
    assert not refused.allowed and refused.retry_after_s == 3
    assert refused.headers(rate.policy)["RateLimit"] == '"requests";r=0;t=7'


def test_a_rate_of_zero_is_no_bound() -> None:
    assert not TenantRate(rate=0.0, burst=1).enabled


def test_the_table_forgets_refilled_buckets_of_many_tenants() -> None:
    clock = _Clock()
    rate = TenantRate(rate=1.0, burst=1, clock=clock)
    for i in range(100):
        rate.take(f"t{i}")
    clock.now += 5.0
    rate.take("late")
    assert list(rate._buckets) == ["late"]


@pytest.fixture(scope="module")
def rated_api(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ApiServer]:
    settings = {
        "BFIELDS_API_TENANT_RATE": str(RATE),
        "BFIELDS_API_TENANT_BURST": str(BURST),
        "BFIELDS_API_TENANT_RATE_DELAY_S": str(DELAY_S),
        "BFIELDS_METRICS_PER_TENANT": "true",
    }
    with lone_api(tmp_path_factory.mktemp("tenant-rate"), settings) as api:
        yield api


def _remaining(resp: httpx.Response) -> int:
    found = re.fullmatch(r'"requests";r=(\d+);t=(\d+)', resp.headers["RateLimit"])
    assert found, resp.headers["RateLimit"]
    return int(found.group(1))


@pytest.mark.integration
@pytest.mark.slow
def test_past_its_burst_a_tenant_waits_its_turn_then_gets_429_while_another_is_served(
    rated_api: ApiServer,
) -> None:
    api = rated_api
    with api.client("tenant-a") as a, api.client("tenant-b") as b:
        served = [a.get("/v1/jobs") for _ in range(BURST)]
        assert [r.status_code for r in served] == [200] * BURST
        remaining = [_remaining(r) for r in served]
        assert remaining == sorted(remaining, reverse=True) and remaining[-1] <= 1
        assert served[0].headers["RateLimit-Policy"] == f'"requests";q=1;w={round(1 / RATE)}'

        # the next one waits for its token (1 / RATE = 2 s, at most DELAY_S), then is served; one
        # sent while it waits would wait 4 s: refused at once, told when to come back
        with ThreadPoolExecutor(1) as pool:
            t0 = time.monotonic()
            waiting = pool.submit(a.get, "/v1/jobs")
            while not waiting.done() and time.monotonic() - t0 < 0.5:  # until it has reserved its turn
                time.sleep(0.05)
            other = a.get("/v1/jobs")
            first = waiting.result()
        # (on a machine so slow that the first had not reached the API within 0.5 s, the two swap)
        waited, refused = (first, other) if first.status_code == 200 else (other, first)
        assert waited.status_code == 200 and time.monotonic() - t0 >= 1.0 / RATE - 0.2
        assert refused.status_code == 429, refused.text
        wait_s = int(refused.headers["Retry-After"])
        assert 1 <= wait_s <= round(2 / RATE - DELAY_S)
        assert "BFIELDS_API_TENANT_RATE" in assert_problem(refused, 429, "too-many-requests")["detail"]
        assert _remaining(refused) == 0

        # the other tenant's bucket is its own; no key is no tenant's (401, never 429)
        t0 = time.monotonic()
        assert b.get("/v1/jobs").status_code == 200
        assert time.monotonic() - t0 < 1.0 / RATE  # it did not wait for A's turn
        assert httpx.get(f"{api.base_url}/v1/jobs", timeout=30).status_code == 401
        assert httpx.get(f"{api.base_url}/healthz", timeout=30).status_code == 200

        time.sleep(wait_s)  # as a client that honours Retry-After: let in (waiting at most DELAY_S)
        assert a.get("/v1/jobs").status_code == 200
    assert re.search(r'^bfields_api_tenant_rate_refused_total\{tenant="tenant-a"} 1\.0$', api.metrics(), re.M)
