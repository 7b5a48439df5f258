"""Callbacks: an HMAC-signed POST to a job's or a batch's ``callback_url`` on its terminal state.

Delivery is *at least once*, never on the job's path, through a **transactional outbox** in the
records database (`callback_outbox`):
- an event row is inserted in the same transaction as the state change that causes it: a job's row
  turning terminal (`on_job_terminal`), or the batch's end that the same transaction decides
  (`on_batch_finished`, `records.batches.mark_finished`); ``event_id`` is unique, so a repeated
  transition adds nothing, and a crash before the commit loses both or neither;
- every worker runs a `CallbackSender`: a dispatcher thread that reads due rows and *claims* one
  (an UPDATE that moves its ``next_attempt_at`` `callback_lease_s` ahead only while it is still
  due, so two workers never send one event at the same time) and hands each to a small pool of
  delivery threads (`callback_threads`), at most `callback_per_destination` of them to one
  host:port, so a slow or hostile receiver holds only its own share and delays only its own
  events. An attempt POSTs and on a 2xx marks the row delivered; on anything else it reschedules
  it with exponential backoff (`callback_backoff_s` doubling, jittered, at most
  `callback_backoff_max_s`) up to `callback_max_attempts`, then marks it dropped with an error
  log. A worker killed mid-POST leaves the claim, which falls due again after the lease: the event
  is sent again (hence *at least once*). Receivers deduplicate on ``webhook-id`` or the body's
  ``event_id`` (one id per event, the same on every attempt).
- one attempt (resolve, connect, send, read the answer) ends by `callback_timeout_s` whatever the
  receiver does (`callback_delivery`), and the claim lasts that plus a margin
  (`ServiceSettings.callback_lease_s`), so an attempt never outlives its claim: no event is in
  flight twice while its sender lives.
The body is JSON, signed by Standard Webhooks headers (`signing`: ``webhook-id``, the same on
every attempt of an event, ``webhook-timestamp`` of the attempt and ``webhook-signature``), so a
receiver's Standard Webhooks library checks both the sender and the freshness; the former
``X-BFields-Signature`` / ``X-BFields-Timestamp`` pair is sent beside them for one release
(deprecated). Nothing of this is in Redis: losing Redis loses no callback.

URLs are checked when a job is submitted and again before each POST by the same function
(`callback_destinations.check_destination`): http or https only, no credentials, a valid host name,
the host in `callback_allowed_hosts` when that is set, and every address it resolves to globally
routable (embedded IPv4 included) unless `callback_allow_private`. The POST then connects to one
of the addresses just checked, never to a second DNS answer.
"""

from __future__ import annotations

import functools
import json
import logging
import random
import threading
import time
from collections import Counter
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import wait as wait_futures
from datetime import datetime
from typing import Any, Protocol

import httpcore
from sqlalchemy import Connection, Engine
from sqlalchemy.exc import DBAPIError

from bayesian_fields_core.errors import InputError
from bayesian_fields_service import records
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.records import outbox
from bayesian_fields_service.webhooks.callback_delivery import TRANSPORT_ERRORS, post
from bayesian_fields_service.webhooks.callback_destinations import (
    Resolver,
    check_destination,
    parse_destination,
)
from bayesian_fields_service.webhooks.signing import signed_headers

log = logging.getLogger(__name__)

#: Due rows the dispatcher reads at a time, and at most per pass, looking for events whose
#: destination has room: events queued for a busy receiver are skipped, not waited behind, so a
#: backlog of up to SCAN_MAX of them for one slow receiver delays no one else's.
SCAN_WINDOW = 256
SCAN_MAX = 4096


# ---- URL rules -------------------------------------------------------------------------------
def check_callback_url(url: str, settings: ServiceSettings, *, resolve: Resolver | None = None) -> str:
    """The URL if a callback may go there, else `InputError` naming the rule (422 at the API).
    The URL is kept as given; every use parses it again the same way (`parse_destination`)."""
    check_destination(url, settings, resolve)
    return url


# ---- the outbox ------------------------------------------------------------------------------
def enqueue(conn: Connection, tenant: str, url: str, event: dict[str, Any]) -> bool:
    """Put one event in the outbox in `conn`'s transaction (False when an event of that id is
    already there)."""
    return outbox.enqueue(conn, tenant, url, event["event_id"], event)


class TerminalJob(Protocol):
    """What `on_job_terminal` reads of a job record."""

    id: str
    tenant: str
    scene_id: str
    error: str | None
    batch_id: str | None
    callback_url: str | None
    finished_at: datetime | None

    @property
    def state(self) -> Any: ...


class FinishedBatch(Protocol):
    """What `on_batch_finished` reads of a batch whose last active job just ended."""

    id: str
    tenant: str
    callback_url: str | None
    total: int
    counts: dict[str, int]
    finished_at: datetime | None


def _iso(when: datetime | None) -> str | None:
    return when.isoformat() if when is not None else None


#: An event for the outbox: (tenant, callback URL, event with its `event_id`).
Event = tuple[str, str, dict[str, Any]]


def job_event(job: TerminalJob) -> Event | None:
    """The job's ``job.finished`` event, when it has a callback_url (None otherwise). Pure: the
    jobs domain queues it in the transaction of the job's terminal write."""
    if not job.callback_url:
        return None
    state = str(getattr(job.state, "value", job.state))
    finished = _iso(job.finished_at)
    return job.tenant, job.callback_url, {
        "event_id": f"job:{job.id}:{state}:{finished}", "type": "job.finished",
        "job_id": job.id, "tenant": job.tenant, "scene_id": job.scene_id, "batch_id": job.batch_id,
        "state": state, "error": job.error, "finished_at": finished,
    }  # fmt: skip


def batch_event(batch: FinishedBatch) -> Event | None:
    """The batch's ``batch.finished`` event, when it has a callback_url. The records decide that
    the batch finished (`records.batches.mark_finished`, once per finish: a retry opens it
    again), so the event id carries the finish time and a retried batch that finishes again
    sends a second event."""
    if not batch.callback_url:
        return None
    finished = _iso(batch.finished_at)
    return batch.tenant, batch.callback_url, {
        "event_id": f"batch:{batch.id}:finished:{finished}", "type": "batch.finished",
        "batch_id": batch.id, "tenant": batch.tenant, "jobs": batch.total,
        "counts": {k: v for k, v in batch.counts.items() if v}, "finished_at": finished,
    }  # fmt: skip


def on_job_terminal(conn: Connection, job: TerminalJob) -> None:
    """`job_event` put in the outbox in `conn`'s transaction (the job's terminal write)."""
    if (event := job_event(job)) is not None:
        enqueue(conn, *event)


def on_batch_finished(conn: Connection, batch: FinishedBatch) -> None:
    """`batch_event` put in the outbox in `conn`'s transaction."""
    if (event := batch_event(batch)) is not None:
        enqueue(conn, *event)


def _backoff(settings: ServiceSettings, attempts: int) -> float:
    delay = min(settings.callback_backoff_max_s, settings.callback_backoff_s * 2 ** (attempts - 1))
    return delay * random.uniform(0.8, 1.2)


def _headers(settings: ServiceSettings, event_id: str, body: bytes) -> dict[str, str]:
    """An attempt's headers: signed now (the timestamp is this attempt's; the id is the event's)."""
    assert settings.callback_secret is not None  # checked by check_destination
    return {
        "Content-Type": "application/json",
        **signed_headers(settings.callback_secret.get_secret_value(), event_id, body),
        "User-Agent": "bayesian-fields-callback/1",
    }


def attempt(
    url: str, event_id: str, body: bytes, settings: ServiceSettings, *, deadline: float,
    resolve: Resolver | None = None,
) -> tuple[bool, str]:  # fmt: skip
    """One signed POST of `body`, done by `deadline` (monotonic): (delivered, what happened).
    The URL is checked again first (the name may resolve elsewhere by now) and the connection
    goes to an address that check approved; the next one is tried only when connecting failed."""
    try:
        dest, addresses = check_destination(url, settings, resolve, timeout_s=deadline - time.monotonic())
    except InputError as exc:
        return False, f"refused: {exc}"
    headers = _headers(settings, event_id, body)
    why = "no address"
    for address in addresses:
        try:
            answer = post(dest, address, body, headers, deadline=deadline,
                          max_bytes=settings.callback_max_response_bytes)  # fmt: skip
        except httpcore.ConnectError as exc:
            why = f"{address}: ConnectError: {exc}"
            continue
        except TRANSPORT_ERRORS as exc:
            return False, f"{address}: {type(exc).__name__}: {exc}"
        if 300 <= answer.status < 400:
            return False, f"HTTP {answer.status} (redirects are not followed)"
        return 200 <= answer.status < 300, f"HTTP {answer.status}"
    return False, why


def settle(database: Engine, settings: ServiceSettings, row_id: int, event_id: str, url: str, attempts: int,
           ok: bool, why: str) -> str:  # fmt: skip
    """Record an attempt's outcome: mark a delivered event, reschedule a failed one with backoff,
    or drop it (marked, logged) after `callback_max_attempts`. Only an open row changes: one
    settled or removed while its attempt was in flight is not brought back."""
    delay = 0.0
    if ok:
        outcome = "delivered"
    elif attempts + 1 >= settings.callback_max_attempts:
        log.error("callback %s to %s dropped after %d attempts: %s", event_id, url, attempts + 1, why)
        outcome = "dropped"
    else:
        delay = _backoff(settings, attempts + 1)
        log.warning("callback %s attempt %d failed (%s); next in %.1f s", event_id, attempts + 1, why, delay)
        outcome = "retry"
    with records.begin(database) as conn:
        if outcome == "delivered":
            changed = outbox.mark_delivered(conn, row_id, attempts + 1)
        elif outcome == "dropped":
            changed = outbox.mark_dropped(conn, row_id, attempts + 1, why)
        else:
            changed = outbox.reschedule(conn, row_id, attempts + 1, why, delay)
    return f"{event_id}: {outcome if changed else 'gone'}"


def _deliver_claimed(database: Engine, settings: ServiceSettings, row_id: int, claimed_at: float,
                     resolve: Resolver | None) -> str:  # fmt: skip
    """Attempt and settle an event this process has just claimed (at monotonic `claimed_at`)."""
    with records.connect(database) as conn:
        row = outbox.load_open(conn, row_id)
    if row is None:  # settled by someone else meanwhile
        return f"{row_id}: gone"
    body = json.dumps(row["event"], sort_keys=True).encode()
    deadline = claimed_at + settings.callback_timeout_s
    ok, why = attempt(row["url"], row["event_id"], body, settings, deadline=deadline, resolve=resolve)
    return settle(database, settings, row_id, row["event_id"], row["url"], row["attempts"], ok, why)


def _claim(database: Engine, settings: ServiceSettings, row_id: int) -> bool:
    """Move a due row's next attempt `callback_lease_s` ahead, only if it is still due and open
    (another worker may have claimed it meanwhile)."""
    with records.begin(database) as conn:
        return outbox.claim(conn, row_id, settings.callback_lease_s)


def _due(database: Engine, offset: int, limit: int) -> list[tuple[int, str]]:
    """(row id, url) of due events, oldest due first."""
    with records.connect(database) as conn:
        return outbox.due(conn, offset, limit)


def deliver_one(
    database: Engine, settings: ServiceSettings, *, resolve: Resolver | None = None
) -> str | None:
    """Claim and POST the first due event in this thread; its id and outcome, or None when none
    is due (`CallbackSender` does the same through its bounded pool)."""
    for row_id, _ in _due(database, 0, 8):
        claimed_at = time.monotonic()
        if _claim(database, settings, row_id):
            return _deliver_claimed(database, settings, row_id, claimed_at, resolve)
    return None


def destination_key(url: str) -> str:
    """host:port of a stored event's URL (what the per-destination bound counts); a URL that no
    longer parses shares one key, and its attempt fails at the check."""
    return _url_key(url) if isinstance(url, str) else "(invalid)"


@functools.lru_cache(maxsize=4096)
def _url_key(url: str) -> str:
    """`destination_key` of one URL, cached: the dispatcher asks for the same URLs every pass."""
    try:
        return parse_destination(url).key
    except InputError:
        return "(invalid)"


class CallbackSender:
    """A worker's callback delivery: a dispatcher thread and a bounded pool of delivery threads.

    The dispatcher claims an event only when a delivery thread is free *and* the event's
    destination has fewer than `callback_per_destination` attempts in flight here, so a claimed
    event starts at once (its deadline and lease run from the claim) and a receiver that holds its
    attempts to the deadline occupies at most its own share of the threads."""

    def __init__(
        self, database: Engine, settings: ServiceSettings, *, resolve: Resolver | None = None
    ) -> None:
        self.database = database
        self.settings = settings
        self.resolve = resolve
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._lock = threading.Lock()
        self._busy: Counter[str] = Counter()  # destination key -> attempts in flight
        self._futures: set[Future[str]] = set()
        self._thread: threading.Thread | None = None
        self._pool: ThreadPoolExecutor | None = None
        self.outcomes: list[str] = []  # the latest outcomes (bounded), for logs and tests

    def start(self) -> None:
        if self.settings.callback_secret is None:
            return  # callbacks are refused at submission; nothing to send
        self._pool = ThreadPoolExecutor(self.settings.callback_threads, thread_name_prefix="bfields-callback")
        self._thread = threading.Thread(target=self._run, name="bfields-callbacks", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop claiming; wait for the attempts in flight (each ends by its deadline)."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        if self._pool is not None:
            with self._lock:
                pending = set(self._futures)
            wait_futures(pending, timeout=self.settings.callback_timeout_s + 5)
            self._pool.shutdown(wait=False, cancel_futures=True)

    def in_flight(self) -> dict[str, int]:
        with self._lock:
            return {k: n for k, n in self._busy.items() if n}

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._dispatch()
            except DBAPIError as exc:
                log.warning("callback delivery: the records database is unavailable (%s)", exc)
            except Exception:  # never let the thread die: log and go on
                log.exception("callback dispatch failed")
            self._wake.wait(self.settings.callback_poll_s)
            self._wake.clear()

    def _dispatch(self) -> None:
        """Claim what the free threads and destinations allow, and start each claimed attempt."""
        with self._lock:
            free = self.settings.callback_threads - sum(self._busy.values())
        if free <= 0:
            return
        for offset in range(0, SCAN_MAX, SCAN_WINDOW):
            due = _due(self.database, offset, SCAN_WINDOW)
            if not due:
                return
            free = self._start_some(due, free)
            if free <= 0 or self._stop.is_set() or len(due) < SCAN_WINDOW:
                return

    def _start_some(self, due: list[tuple[int, str]], free: int) -> int:
        """Claim and start those of `due` whose destination has room, up to `free`; what is left
        of `free`. (Claiming shifts the due rows, so a later page may skip or repeat a row: a
        skipped one is found next pass, a repeated one is refused by its claim.)"""
        for row_id, url in due:
            if free <= 0 or self._stop.is_set():
                break
            key = destination_key(url)
            with self._lock:
                if self._busy[key] >= self.settings.callback_per_destination:
                    continue
            claimed_at = time.monotonic()
            if not _claim(self.database, self.settings, row_id):
                continue  # another worker claimed it first
            with self._lock:
                self._busy[key] += 1
                assert self._pool is not None
                future = self._pool.submit(self._deliver, row_id, key, claimed_at)
                self._futures.add(future)
            free -= 1
        return free

    def _deliver(self, row_id: int, key: str, claimed_at: float) -> str:
        try:
            outcome = _deliver_claimed(self.database, self.settings, row_id, claimed_at, self.resolve)
        except Exception as exc:  # the database gone mid-way: the claim expires and the event is retried
            log.exception("callback %s delivery failed", row_id)
            outcome = f"{row_id}: error {type(exc).__name__}"
        finally:
            with self._lock:
                self._busy[key] -= 1
                self._futures = {f for f in self._futures if not f.done()}
            self._wake.set()
        with self._lock:
            self.outcomes.append(outcome)
            del self.outcomes[:-1000]
        return outcome
