"""Callbacks: an HMAC-signed POST to a job's or a batch's ``callback_url`` on its terminal state.

Delivery is *at least once*, never on the job's path:
- when a job's manifest turns terminal (`JobStore` calls `on_job_terminal` under the manifest lock,
  once per transition), the event is put in a Redis outbox: the body in ``bf:cb:items`` (by event
  id; HSETNX, so a repeated transition adds nothing) and the id in the ``bf:cb:due`` sorted set,
  scored by when it is due;
- a batch's event is added when its last job turns terminal (``bf:batch-states:<tenant>:<id>``
  holds each finished job's state; the event once per distinct outcome);
- every worker runs a delivery thread (`CallbackSender`): it *claims* the first due id by moving
  its score past the POST's timeout (one Lua call: two workers never send one event at the same
  time), POSTs, and on a 2xx deletes it; on anything else it reschedules it with exponential
  backoff (`callback_backoff_s` doubling, jittered, at most `callback_backoff_max_s`) up to
  `callback_max_attempts`, then drops it with an error log. A worker killed mid-POST leaves the
  claim, which falls due again after the lease: the event is sent again (hence *at least once*).
  Receivers deduplicate on ``event_id`` (the body's idempotency key, also a header).
The body is JSON; ``X-BFields-Timestamp`` is the Unix time of the attempt and
``X-BFields-Signature`` is ``sha256=`` + hex HMAC-SHA256(secret, timestamp + "." + body), so a
receiver checks both the sender and the freshness. The outbox lives in Redis: run it with AOF
persistence (as the queue itself needs) or a Redis loss also loses the undelivered callbacks.

URLs are checked when a job is submitted and again before each POST (the name may resolve
elsewhere by then): http or https only, no credentials, the host in `callback_allowed_hosts`
when that is set, and no loopback / private / link-local / reserved address unless
`callback_allow_private`.
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import json
import logging
import random
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable
from datetime import datetime
from typing import Any, Protocol
from urllib.parse import urlsplit

import httpx
import redis

from bayesian_fields_core.errors import InputError
from bayesian_fields_service.common.redis_text import text
from bayesian_fields_service.common.settings import ServiceSettings

log = logging.getLogger(__name__)

ITEMS = "bf:cb:items"
DUE = "bf:cb:due"
DEAD = "bf:cb:dead"
SIGNATURE_HEADER = "X-BFields-Signature"
TIMESTAMP_HEADER = "X-BFields-Timestamp"
EVENT_HEADER = "X-BFields-Event-Id"

#: Claim the first due event: push its score `lease` seconds ahead and return its id.
_CLAIM = """
local ids = redis.call('zrangebyscore', KEYS[1], '-inf', ARGV[1], 'LIMIT', 0, 1)
if #ids == 0 then return false end
redis.call('zadd', KEYS[1], ARGV[1] + ARGV[2], ids[1])
return ids[1]
"""


# ---- URL rules -------------------------------------------------------------------------------
def _blocked(ip: ipaddress.IPv4Address | ipaddress.IPv6Address) -> bool:
    return (
        ip.is_loopback or ip.is_private or ip.is_link_local or ip.is_reserved
        or ip.is_multicast or ip.is_unspecified
    )  # fmt: skip


def _host_allowed(host: str, allowed: list[str]) -> bool:
    for pattern in allowed:
        p = pattern.lower().rstrip(".")
        if p.startswith("*.") and (host.endswith(p[1:]) or host == p[2:]):
            return True
        if host == p:
            return True
    return False


def check_callback_url(
    url: str, settings: ServiceSettings, *, resolve: Callable[[str], list[str]] | None = None
) -> str:
    """The URL if a callback may go there, else `InputError` naming the rule (422 at the API)."""
    source = "callback_url"
    if settings.callback_secret is None:
        raise InputError(
            "callbacks are not enabled on this service (no BFIELDS_CALLBACK_SECRET)", source=source
        )
    if len(url) > 2000:
        raise InputError("longer than 2000 characters", source=source)
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https"):
        raise InputError(f"scheme {parts.scheme!r} is not allowed (http or https)", source=source)
    if parts.username or parts.password:
        raise InputError("credentials in the URL are not allowed", source=source)
    host = (parts.hostname or "").lower().rstrip(".")
    if not host:
        raise InputError("the URL names no host", source=source)
    if settings.callback_allowed_hosts and not _host_allowed(host, settings.callback_allowed_hosts):
        raise InputError(f"host {host!r} is not in BFIELDS_CALLBACK_ALLOWED_HOSTS", source=source)
    if not settings.callback_allow_private:
        try:
            addresses = (resolve or _resolve)(host)
        except OSError:
            raise InputError(f"host {host!r} does not resolve", source=source) from None
        for address in addresses:
            if _blocked(ipaddress.ip_address(address.split("%")[0])):
                raise InputError(
                    f"host {host!r} is a loopback, private or reserved address ({address}); "
                    "allowed only with BFIELDS_CALLBACK_ALLOW_PRIVATE",
                    source=source,
                )
    return url


def _resolve(host: str) -> list[str]:
    try:
        return [str(ipaddress.ip_address(host))]
    except ValueError:
        return sorted({str(info[4][0]) for info in socket.getaddrinfo(host, None)})


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


class BatchInfo(Protocol):
    id: str
    job_ids: list[str]
    callback_url: str | None


def _iso(when: datetime | None) -> str | None:
    return when.isoformat() if when is not None else None


def on_job_terminal(
    client: redis.Redis, job: TerminalJob, load_batch: Callable[[str, str], BatchInfo | None]
) -> None:
    """The job's event (when it has a callback_url) and, when it is its batch's last, the batch's."""
    state = str(getattr(job.state, "value", job.state))
    finished = _iso(job.finished_at)
    if job.callback_url:
        enqueue(client, job.callback_url, {
            "event_id": f"job:{job.id}:{state}:{finished}", "type": "job.finished",
            "job_id": job.id, "tenant": job.tenant, "scene_id": job.scene_id, "batch_id": job.batch_id,
            "state": state, "error": job.error, "finished_at": finished,
        })  # fmt: skip
    if not job.batch_id:
        return
    states_key = f"bf:batch-states:{job.tenant}:{job.batch_id}"
    client.hset(states_key, job.id, state)
    client.expire(states_key, 30 * 24 * 3600)
    batch = load_batch(job.tenant, job.batch_id)
    if batch is None or not batch.callback_url:
        return
    states = {text(k): text(v) for k, v in client.hgetall(states_key).items()}
    if not set(batch.job_ids) <= set(states):
        return
    counts = Counter(states[j] for j in batch.job_ids)
    outcome = hashlib.sha256(json.dumps(sorted(states.items())).encode()).hexdigest()[:16]
    enqueue(client, batch.callback_url, {
        "event_id": f"batch:{batch.id}:finished:{outcome}", "type": "batch.finished",
        "batch_id": batch.id, "tenant": job.tenant, "jobs": len(batch.job_ids), "counts": dict(counts),
        "finished_at": finished,
    })  # fmt: skip


def _backoff(settings: ServiceSettings, attempts: int) -> float:
    delay = min(settings.callback_backoff_max_s, settings.callback_backoff_s * 2 ** (attempts - 1))
    return delay * random.uniform(0.8, 1.2)


def deliver_one(client: redis.Redis, settings: ServiceSettings, http: httpx.Client) -> str | None:
    """Claim and POST the first due event; returns its id and outcome, or None when none is due."""
    lease = settings.callback_timeout_s + 30
    claimed = client.eval(_CLAIM, 1, DUE, time.time(), lease)
    if not claimed:
        return None
    event_id = text(claimed)
    raw = client.hget(ITEMS, event_id)
    if raw is None:  # delivered by someone else meanwhile
        client.zrem(DUE, event_id)
        return f"{event_id}: gone"
    item = json.loads(raw)
    body = json.dumps(item["event"], sort_keys=True).encode()
    ok, why = False, ""
    try:
        check_callback_url(item["url"], settings)  # again: DNS may have changed since submission
        assert settings.callback_secret is not None
        ts = str(int(time.time()))
        headers = {
            "Content-Type": "application/json",
            TIMESTAMP_HEADER: ts,
            SIGNATURE_HEADER: signature(settings.callback_secret.get_secret_value(), ts, body),
            EVENT_HEADER: event_id,
            "User-Agent": "bayesian-fields-callback/1",
        }
        resp = http.post(item["url"], content=body, headers=headers)
        ok, why = 200 <= resp.status_code < 300, f"HTTP {resp.status_code}"
    except InputError as exc:
        why = f"refused: {exc}"
    except httpx.HTTPError as exc:
        why = f"{type(exc).__name__}: {exc}"
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
    pipe = client.pipeline()
    pipe.hset(ITEMS, event_id, json.dumps(item))
    pipe.zadd(DUE, {event_id: time.time() + delay})
    pipe.execute()
    return f"{event_id}: retry"


class CallbackSender:
    """A worker's delivery thread: sends due callbacks until stopped."""

    def __init__(self, client: redis.Redis, settings: ServiceSettings) -> None:
        self.client = client
        self.settings = settings
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self.settings.callback_secret is None:
            return  # callbacks are refused at submission; nothing to send
        self._thread = threading.Thread(target=self._run, name="bfields-callbacks", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self.settings.callback_timeout_s + 5)

    def _run(self) -> None:
        with httpx.Client(timeout=self.settings.callback_timeout_s, follow_redirects=False) as http:
            while not self._stop.is_set():
                try:
                    while not self._stop.is_set() and deliver_one(self.client, self.settings, http):
                        pass
                except redis.RedisError as exc:
                    log.warning("callback delivery: Redis unavailable (%s)", exc)
                except Exception:  # never let the thread die: log and go on
                    log.exception("callback delivery failed")
                self._stop.wait(self.settings.callback_poll_s)
