"""Callback delivery that no receiver can stall (issue 30, item 5), on the real stack: a real control
process (`bfields-service control`: its `CallbackSender` is what delivers), real PostgreSQL (the
outbox table, a database of this module's own), and real HTTP receivers (`callback_receivers`) that
drip, send hundreds of MB, never answer, redirect or fail once.

The control process runs with the shipped defaults for delivery threads, the per-destination bound
and the answer cap (settings.py), and a short attempt deadline so the tests are quick. Events go into the
outbox exactly as a finished job puts them there (`callbacks.enqueue`); the
records database and the receivers are this folder's (conftest.py)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest
from sqlalchemy import Engine

from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.webhooks import callbacks, signing
from tests.integration.fixtures.services import ControlServer
from tests.services.support.callback_receivers import Receiver, RssSampler, overlapping
from tests.services.support.outbox_events import dropped as _dead
from tests.services.support.outbox_events import enqueue as _enqueue
from tests.services.support.outbox_events import pending as _pending
from tests.services.support.outbox_events import wait_for as _wait

pytestmark = [pytest.mark.integration]

SECRET = "test-callback-secret"
TIMEOUT_S = 4.0
MAX_ATTEMPTS = 3
WORKER_ENV = {
    "BFIELDS_CALLBACK_SECRET": SECRET,
    "BFIELDS_CALLBACK_ALLOW_PRIVATE": "true",  # the receivers are on 127.0.0.1
    "BFIELDS_CALLBACK_TIMEOUT_S": str(TIMEOUT_S),
    "BFIELDS_CALLBACK_MAX_ATTEMPTS": str(MAX_ATTEMPTS),
    "BFIELDS_CALLBACK_BACKOFF_S": "0.5",
    "BFIELDS_CALLBACK_POLL_S": "0.2",
}
#: The shipped defaults, read from the one place they are written.
FIELDS = ServiceSettings.model_fields
THREADS: int = FIELDS["callback_threads"].default
PER_DESTINATION: int = FIELDS["callback_per_destination"].default
MAX_RESPONSE: int = FIELDS["callback_max_response_bytes"].default
#: An attempt ends by its deadline; this much later is scheduling, not the receiver.
SLACK_S = 1.0


@pytest.fixture(scope="module")
def callback_worker(
    svc_env: dict[str, str], outbox_url: str, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[ControlServer]:
    """One real control process: with no job in its database, it only sends callbacks."""
    env = {**svc_env, **WORKER_ENV, "BFIELDS_DATABASE_URL": outbox_url}
    control = ControlServer(env, tmp_path_factory.mktemp("callback-control")).start()
    assert control.leads
    yield control
    control.stop()


def test_ordinary_callback_on_time_while_drip_and_huge_receivers_are_served(
    callback_worker: ControlServer, outbox: Engine, receivers: Callable[..., Receiver]
) -> None:
    """More drip events than the per-destination bound and 400 MB answers do not delay an ordinary
    callback; the drip attempts end by the deadline, one at a time per event, at most
    `callback_per_destination` at once, and are dropped after the attempts; the huge answers are
    cut off after the cap (delivered: the status was 2xx) and the worker's memory hardly moves."""
    drip, huge, ok = receivers("drip", drip_s=1.5), receivers("huge"), receivers("ok")
    warm = _enqueue(outbox, ok.url("/warm"), "ordinary")  # the sender is up and its first use done
    _wait(lambda: warm in ok.events() and not _pending(outbox, [warm]), 15, "a warm-up delivery")
    assert callback_worker.process.pid is not None
    rss = RssSampler(callback_worker.process.pid)

    drips = [_enqueue(outbox, drip.url(), "drip") for _ in range(PER_DESTINATION + 1)]
    huges = [_enqueue(outbox, huge.url(), "huge") for _ in range(4)]
    _wait(lambda: drip.in_flight == PER_DESTINATION, 5, "the drip receiver holding its share")
    t0 = time.monotonic()
    ordinary = _enqueue(outbox, ok.url("/ordinary"), "ordinary")
    _wait(lambda: ordinary in ok.events(), 5, "the ordinary callback")
    hit = next(h for h in ok.snapshot() if h.event_id == ordinary)
    latency = hit.start - t0
    drip_serving = drip.in_flight
    _wait(lambda: not _pending(outbox, huges), 15, "the huge-body events settled")
    growth = rss.stop()

    huge_hits = huge.snapshot()
    print(f"\nordinary callback delivered {latency * 1000:.0f} ms after enqueue, drip attempts in flight "
          f"then: {drip_serving}; huge answers: {len(huge_hits)} attempts, bytes the receiver got out "
          f"before the worker closed: {[h.sent for h in huge_hits]} (of {huge.body_bytes} each); worker "
          f"RSS {rss.baseline:.0f} MiB, peak growth {growth:.1f} MiB")  # fmt: skip
    assert latency < 1.5, latency
    assert drip_serving >= 1  # it arrived while the drip receiver was still being served
    assert sorted(h.event_id for h in huge_hits) == sorted(huges)  # one attempt each: 200 = delivered
    assert all(h.sent < 64 * 1024 * 1024 for h in huge_hits)  # cut off, not read
    assert not set(huges) & set(_dead(outbox))
    assert growth < 50, f"the worker grew by {growth:.0f} MiB reading {len(huge_hits)} huge answers"

    # the drip events: every attempt ended by the deadline, never two of one event at once, at most
    # the per-destination bound in flight, and each event dropped after its attempts
    _wait(lambda: set(drips) <= set(_dead(outbox)), MAX_ATTEMPTS * (TIMEOUT_S + 2) * 2 + 10, "drips dropped")
    hits = drip.snapshot()
    durations = [h.end - h.start for h in hits if h.end is not None]
    print(f"drip attempts: {len(hits)}, longest {max(durations):.2f} s (deadline {TIMEOUT_S} s), "
          f"most in flight at once {drip.max_in_flight}")  # fmt: skip
    assert sorted(h.event_id for h in hits) == sorted(drips * MAX_ATTEMPTS)
    assert max(durations) <= TIMEOUT_S + SLACK_S and len(durations) == len(hits)
    assert drip.max_in_flight <= PER_DESTINATION
    assert overlapping(hits) == []
    assert all("Timeout" in _dead(outbox)[e]["last_error"] for e in drips), _dead(outbox)


def test_silent_receiver_two_senders_never_in_flight_twice(
    callback_worker: ControlServer, outbox: Engine, receivers: Callable[..., Receiver], redis_url: str
) -> None:
    """A receiver that never answers: each attempt ends at the deadline, the event is dropped after
    `callback_max_attempts`, and with two senders competing (the control process and a second sender
    in this process, as two leaders at once would) no event is ever POSTed twice at the same time: the claim outlives
    the attempt."""
    silent = receivers("silent")
    settings = ServiceSettings(redis_url=redis_url, **{k[8:].lower(): v for k, v in WORKER_ENV.items()})  # type: ignore[arg-type]
    assert settings.callback_lease_s > settings.callback_timeout_s
    second = callbacks.CallbackSender(outbox, settings)
    second.start()
    try:
        events = [_enqueue(outbox, silent.url(), "silent") for _ in range(3)]
        _wait(
            lambda: set(events) <= set(_dead(outbox)), MAX_ATTEMPTS * (TIMEOUT_S + 2) + 10, "silent dropped"
        )
    finally:
        second.stop()
    hits = silent.snapshot()
    durations = [h.end - h.start for h in hits if h.end is not None]
    mine = [o for o in second.outcomes if o.startswith("test:silent")]
    print(f"\nsilent receiver: {len(hits)} attempts, {len(mine)} by the second sender, each "
          f"{min(durations):.2f}-{max(durations):.2f} s (deadline {TIMEOUT_S} s)")  # fmt: skip
    assert sorted(h.event_id for h in hits) == sorted(events * MAX_ATTEMPTS)  # no more, no less
    assert max(durations) <= TIMEOUT_S + SLACK_S and min(durations) >= TIMEOUT_S - SLACK_S
    assert overlapping(hits) == []
    assert all(_dead(outbox)[e]["attempts"] == MAX_ATTEMPTS for e in events)


def test_redirect_is_not_followed(
    callback_worker: ControlServer, outbox: Engine, receivers: Callable[..., Receiver]
) -> None:
    """A 302 is a failed attempt (retried, then dropped); its Location is never requested."""
    target = receivers("ok")
    redirect = receivers("redirect", location=target.url("/target"))
    event = _enqueue(outbox, redirect.url(), "redirect")
    _wait(lambda: event in _dead(outbox), 20, "the redirected event dropped")
    assert redirect.events() == [event] * MAX_ATTEMPTS
    assert target.snapshot() == []
    assert "302" in _dead(outbox)[event]["last_error"]


def test_500_then_200_is_retried_and_delivered(
    callback_worker: ControlServer, outbox: Engine, receivers: Callable[..., Receiver]
) -> None:
    """A 500 is retried after the backoff; the 200 that follows delivers it: out of the outbox,
    not dropped, the same event id and body both times, both signed."""
    flaky = receivers("flaky")
    event = _enqueue(outbox, flaky.url(), "flaky")
    _wait(lambda: len(flaky.snapshot()) >= 2 and not _pending(outbox, [event]), 15, "the retry")
    time.sleep(0.5)  # nothing more comes
    first, second = flaky.snapshot()
    assert (first.status, second.status) == (500, 200)
    assert first.event_id == second.event_id == event and first.body == second.body
    assert second.start - first.start >= 0.4  # the backoff (0.5 s, jittered by 20 %)
    for h in (first, second):
        assert signing.verify_legacy(
            SECRET, h.headers["X-BFields-Timestamp"], h.body, h.headers["X-BFields-Signature"]
        )
    assert event not in _dead(outbox)
