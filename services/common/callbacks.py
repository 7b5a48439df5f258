"""Callbacks: an HMAC-signed POST to a job's or a batch's ``callback_url`` on its terminal state.

Delivery is *at least once*, never on the job's path:
- when a job's row turns terminal (`JobStore` calls `on_job_terminal` after the row's
  transaction, once per transition), the event is put in a Redis outbox: the body in ``bf:cb:items`` (by event
  id; HSETNX, so a repeated transition adds nothing) and the id in the ``bf:cb:due`` sorted set,
  scored by when it is due;
- a batch's event is added when its last active job turns terminal: the records database decides
  that (`batch_records.finished_batches`, in the transaction of the state change), once per finish;
- every worker runs a `CallbackSender`: a dispatcher thread that *claims* due events (one Lua call
  per event moves its score `callback_lease_s` ahead, so two workers never send one event at the
  same time) and hands each to a small pool of delivery threads (`callback_threads`), at most
  `callback_per_destination` of them to one host:port, so a slow or hostile receiver holds only
  its own share and delays only its own events. An attempt POSTs and on a 2xx deletes the event;
  on anything else it reschedules it with exponential backoff (`callback_backoff_s` doubling,
  jittered, at most `callback_backoff_max_s`) up to `callback_max_attempts`, then drops it with an
  error log. A worker killed mid-POST leaves the claim, which falls due again after the lease: the
  event is sent again (hence *at least once*). Receivers deduplicate on ``event_id`` (the body's
  idempotency key, also a header).
- one attempt (resolve, connect, send, read the answer) ends by `callback_timeout_s` whatever the
  receiver does (`callback_delivery`), and the claim lasts that plus a margin
  (`ServiceSettings.callback_lease_s`), so an attempt never outlives its claim: no event is in
  flight twice while its sender lives.
The body is JSON; ``X-BFields-Timestamp`` is the Unix time of the attempt and
``X-BFields-Signature`` is ``sha256=`` + hex HMAC-SHA256(secret, timestamp + "." + body), so a
receiver checks both the sender and the freshness. The outbox lives in Redis: run it with AOF
persistence (as the queue itself needs) or a Redis loss also loses the undelivered callbacks.

URLs are checked when a job is submitted and again before each POST by the same function
(`callback_destinations.check_destination`): http or https only, no credentials, a valid host name,
the host in `callback_allowed_hosts` when that is set, and every address it resolves to globally
routable (embedded IPv4 included) unless `callback_allow_private`. The POST then connects to one
of the addresses just checked, never to a second DNS answer.
"""

from __future__ import annotations

import functools
import hashlib
import hmac
import json
import logging
import random
import threading
import time
from collections import Counter
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import wait as wait_futures
from datetime import datetime
from typing import Any, Protocol, cast

import httpcore
import redis

from bayesian_fields_core.errors import InputError
from bayesian_fields_service.common.callback_delivery import TRANSPORT_ERRORS, post
from bayesian_fields_service.common.callback_destinations import (
    Resolver,
    check_destination,
    parse_destination,
)
from bayesian_fields_service.common.redis_text import text
from bayesian_fields_service.common.settings import ServiceSettings

log = logging.getLogger(__name__)

ITEMS = "bf:cb:items"
DUE = "bf:cb:due"
DEAD = "bf:cb:dead"
SIGNATURE_HEADER = "X-BFields-Signature"
TIMESTAMP_HEADER = "X-BFields-Timestamp"
EVENT_HEADER = "X-BFields-Event-Id"
#: Due ids the dispatcher reads at a time, and at most per pass, looking for events whose
#: destination has room: events queued for a busy receiver are skipped, not waited behind, so a
#: backlog of up to SCAN_MAX of them for one slow receiver delays no one else's.
SCAN_WINDOW = 256
SCAN_MAX = 4096

#: Claim the first due event: push its score `lease` seconds ahead and return its id.
_CLAIM_FIRST = """
local ids = redis.call('zrangebyscore', KEYS[1], '-inf', ARGV[1], 'LIMIT', 0, 1)
if #ids == 0 then return false end
redis.call('zadd', KEYS[1], ARGV[1] + ARGV[2], ids[1])
return ids[1]
"""

#: Claim one named event if it is still due (another worker may have claimed it meanwhile).
_CLAIM_ID = """
local score = redis.call('zscore', KEYS[1], ARGV[1])
if not score or tonumber(score) > tonumber(ARGV[2]) then return 0 end
redis.call('zadd', KEYS[1], ARGV[2] + ARGV[3], ARGV[1])
return 1
"""

#: Reschedule a failed event, only while it is still in the outbox: an event removed while its
#: attempt was in flight must not come back.
_RESCHEDULE = """
if redis.call('hexists', KEYS[1], ARGV[1]) == 0 then return 0 end
redis.call('hset', KEYS[1], ARGV[1], ARGV[2])
redis.call('zadd', KEYS[2], ARGV[3], ARGV[1])
return 1
"""


# ---- URL rules -------------------------------------------------------------------------------
def check_callback_url(url: str, settings: ServiceSettings, *, resolve: Resolver | None = None) -> str:
    """The URL if a callback may go there, else `InputError` naming the rule (422 at the API).
    The URL is kept as given; every use parses it again the same way (`parse_destination`)."""
    check_destination(url, settings, resolve)
    return url


# ---- signing ---------------------------------------------------------------------------------
def signature(secret: str, timestamp: str, body: bytes) -> str:
    """``sha256=<hex>`` of HMAC-SHA256(secret, timestamp + "." + body)."""
    mac = hmac.new(secret.encode(), timestamp.encode() + b"." + body, hashlib.sha256)
    return "sha256=" + mac.hexdigest()


def verify(secret: str, timestamp: str, body: bytes, header: str, *, max_age_s: float = 300) -> bool:
    """What a receiver does (documented; used by the tests): signature and freshness."""
    try:
        fresh = abs(time.time() - float(timestamp)) <= max_age_s
    except ValueError:
        return False
    return fresh and hmac.compare_digest(signature(secret, timestamp, body), header)


# ---- the outbox ------------------------------------------------------------------------------
def enqueue(client: redis.Redis, url: str, event: dict[str, Any]) -> bool:
    """Put one event in the outbox (False when an event of that id is already there)."""
    item = json.dumps({"url": url, "event": event, "attempts": 0})
    if not client.hsetnx(ITEMS, event["event_id"], item):
        return False
    client.zadd(DUE, {event["event_id"]: time.time()})
    return True


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


def on_job_terminal(client: redis.Redis, job: TerminalJob) -> None:
    """The job's event, when it has a callback_url."""
    if not job.callback_url:
        return
    state = str(getattr(job.state, "value", job.state))
    finished = _iso(job.finished_at)
    enqueue(client, job.callback_url, {
        "event_id": f"job:{job.id}:{state}:{finished}", "type": "job.finished",
        "job_id": job.id, "tenant": job.tenant, "scene_id": job.scene_id, "batch_id": job.batch_id,
        "state": state, "error": job.error, "finished_at": finished,
    })  # fmt: skip


def on_batch_finished(client: redis.Redis, batch: FinishedBatch) -> None:
    """The batch's event, when it has a callback_url. The records decide that the batch finished
    (`batch_records.finished_batches`, once per finish: a retry opens it again), so the event id
    carries the finish time and a retried batch that finishes again sends a second event."""
    if not batch.callback_url:
        return
    finished = _iso(batch.finished_at)
    enqueue(client, batch.callback_url, {
        "event_id": f"batch:{batch.id}:finished:{finished}", "type": "batch.finished",
        "batch_id": batch.id, "tenant": batch.tenant, "jobs": batch.total,
        "counts": {k: v for k, v in batch.counts.items() if v}, "finished_at": finished,
    })  # fmt: skip


def _backoff(settings: ServiceSettings, attempts: int) -> float:
    delay = min(settings.callback_backoff_max_s, settings.callback_backoff_s * 2 ** (attempts - 1))
    return delay * random.uniform(0.8, 1.2)


def _signed_headers(settings: ServiceSettings, event_id: str, body: bytes) -> dict[str, str]:
    assert settings.callback_secret is not None  # checked by check_destination
    ts = str(int(time.time()))
    return {
        "Content-Type": "application/json",
        TIMESTAMP_HEADER: ts,
        SIGNATURE_HEADER: signature(settings.callback_secret.get_secret_value(), ts, body),
        EVENT_HEADER: event_id,
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
    headers = _signed_headers(settings, event_id, body)
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


def settle(client: redis.Redis, settings: ServiceSettings, event_id: str, item: dict[str, Any],
           ok: bool, why: str) -> str:  # fmt: skip
    """Record an attempt's outcome: delete a delivered event, reschedule a failed one with
    backoff, or drop it (to ``bf:cb:dead``, logged) after `callback_max_attempts`."""
    if ok:
        pipe = client.pipeline()
        pipe.hdel(ITEMS, event_id)
        pipe.zrem(DUE, event_id)
        pipe.execute()
        return f"{event_id}: delivered"
    item["attempts"] += 1
    item["last_error"] = why
    if item["attempts"] >= settings.callback_max_attempts:
        log.error(
            "callback %s to %s dropped after %d attempts: %s", event_id, item["url"], item["attempts"], why
        )
        pipe = client.pipeline()
        pipe.lpush(DEAD, json.dumps(item))
        pipe.ltrim(DEAD, 0, 999)
        pipe.hdel(ITEMS, event_id)
        pipe.zrem(DUE, event_id)
        pipe.execute()
        return f"{event_id}: dropped"
    delay = _backoff(settings, item["attempts"])
    log.warning("callback %s attempt %d failed (%s); next in %.1f s", event_id, item["attempts"], why, delay)
    if not client.eval(_RESCHEDULE, 2, ITEMS, DUE, event_id, json.dumps(item), time.time() + delay):
        return f"{event_id}: gone"  # removed while in flight (an operator, a test): not brought back
    return f"{event_id}: retry"


def _deliver_claimed(client: redis.Redis, settings: ServiceSettings, event_id: str, claimed_at: float,
                     resolve: Resolver | None) -> str:  # fmt: skip
    """Attempt and settle an event this process has just claimed (at monotonic `claimed_at`)."""
    raw = client.hget(ITEMS, event_id)
    if raw is None:  # delivered by someone else meanwhile
        client.zrem(DUE, event_id)
        return f"{event_id}: gone"
    item = json.loads(raw)
    body = json.dumps(item["event"], sort_keys=True).encode()
    deadline = claimed_at + settings.callback_timeout_s
    ok, why = attempt(item["url"], event_id, body, settings, deadline=deadline, resolve=resolve)
    return settle(client, settings, event_id, item, ok, why)


def deliver_one(
    client: redis.Redis, settings: ServiceSettings, *, resolve: Resolver | None = None
) -> str | None:
    """Claim and POST the first due event in this thread; its id and outcome, or None when none
    is due (`CallbackSender` does the same through its bounded pool)."""
    claimed_at = time.monotonic()
    claimed = client.eval(_CLAIM_FIRST, 1, DUE, time.time(), settings.callback_lease_s)
    if not claimed:
        return None
    return _deliver_claimed(client, settings, text(claimed), claimed_at, resolve)


def destination_key(raw_item: bytes | str) -> str:
    """host:port of a stored event's URL (what the per-destination bound counts); an item or URL
    that no longer parses shares one key, and its attempt fails at the check."""
    try:
        url = json.loads(raw_item)["url"]
    except (ValueError, KeyError, TypeError):
        return "(invalid)"
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
        self, client: redis.Redis, settings: ServiceSettings, *, resolve: Resolver | None = None
    ) -> None:
        self.client = client
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
            except redis.RedisError as exc:
                log.warning("callback delivery: Redis unavailable (%s)", exc)
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
        now = time.time()
        for offset in range(0, SCAN_MAX, SCAN_WINDOW):
            due = self.client.zrangebyscore(DUE, "-inf", now, start=offset, num=SCAN_WINDOW)
            ids = [text(i) for i in cast("list[bytes | str]", due)]
            if not ids:
                return
            free = self._start_some(ids, free)
            if free <= 0 or self._stop.is_set() or len(ids) < SCAN_WINDOW:
                return

    def _start_some(self, ids: list[str], free: int) -> int:
        """Claim and start those of `ids` whose destination has room, up to `free`; what is left
        of `free`. (Claiming shifts the due set, so a later page may skip or repeat an id: a skipped
        one is found next pass, a repeated one is refused by its claim.)"""
        for event_id, raw in zip(ids, self.client.hmget(ITEMS, ids), strict=True):
            if free <= 0 or self._stop.is_set():
                break
            if raw is None:  # settled meanwhile (both keys go in one transaction), or an orphan
                self.client.zrem(DUE, event_id)
                continue
            key = destination_key(raw)
            with self._lock:
                if self._busy[key] >= self.settings.callback_per_destination:
                    continue
            claimed_at = time.monotonic()
            if not self.client.eval(_CLAIM_ID, 1, DUE, event_id, time.time(), self.settings.callback_lease_s):
                continue  # another worker claimed it first
            with self._lock:
                self._busy[key] += 1
                assert self._pool is not None
                future = self._pool.submit(self._deliver, event_id, key, claimed_at)
                self._futures.add(future)
            free -= 1
        return free

    def _deliver(self, event_id: str, key: str, claimed_at: float) -> str:
        try:
            outcome = _deliver_claimed(self.client, self.settings, event_id, claimed_at, self.resolve)
        except Exception as exc:  # Redis gone mid-way: the claim expires and the event is retried
            log.exception("callback %s delivery failed", event_id)
            outcome = f"{event_id}: error {type(exc).__name__}"
        finally:
            with self._lock:
                self._busy[key] -= 1
                self._futures = {f for f in self._futures if not f.done()}
            self._wake.set()
        with self._lock:
            self.outcomes.append(outcome)
            del self.outcomes[:-1000]
        return outcome
