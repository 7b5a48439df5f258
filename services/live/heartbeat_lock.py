"""One Redis lock with a heartbeat, for work whose holder may die without a word: a cache fill
(`live.single_flight`). A stage's execution is claimed on the job's row instead
(`records.job_heartbeats`): that is a record, this only saves duplicated work.

The lock is a key holding its owner's token, set with a TTL; a heartbeat thread renews it every
`ttl / beats` seconds while the holder lives, and puts it back if Redis lost it (a restart without
persistence), so a crashed holder's lock expires within the TTL and a living one's never does.
Every change that depends on the owner is one Lua call that compares the token first: renewing,
releasing (a get-then-delete pair could delete a lock that expired and was taken by another worker
in between) and taking over from a dead owner.

Why Redis and not the records database: these locks are renewed several times a minute by every
busy worker and only ever guard work that is safe to repeat; losing them with Redis costs at most a
duplicate computation, which the stages' idempotent artifacts absorb.
"""

from __future__ import annotations

import logging
import threading

import redis

log = logging.getLogger(__name__)

#: Renew when the key is ours or gone (Redis lost it); never when another owner holds it.
_RENEW = """local v = redis.call('get', KEYS[1])
if v == false or v == ARGV[1] then return redis.call('set', KEYS[1], ARGV[1], 'PX', ARGV[2]) and 1 end
return 0"""
#: Delete only our own lock.
_RELEASE = "if redis.call('get', KEYS[1]) == ARGV[1] then return redis.call('del', KEYS[1]) end return 0"
#: Replace a given (dead) owner's token with ours.
_TAKE_OVER = """if redis.call('get', KEYS[1]) == ARGV[1] then
  redis.call('set', KEYS[1], ARGV[2], 'PX', ARGV[3]) return 1 end return 0"""


class HeartbeatLock:
    """`key` held by `token` for `ttl_s`, renewed `beats` times per TTL while held."""

    def __init__(self, client: redis.Redis, key: str, token: str, ttl_s: float, *, beats: int = 4) -> None:
        self.client = client
        self.key = key
        self.token = token
        self.ttl_ms = max(1, int(ttl_s * 1000))
        self.beats = beats
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def acquire(self) -> bool:
        """Take the lock if it is free (and start the heartbeat)."""
        if not self.client.set(self.key, self.token, nx=True, px=self.ttl_ms):
            return False
        self._start()
        return True

    def take_over(self, dead_owner: bytes | str) -> bool:
        """Take the lock from `dead_owner` (the token it holds now, known dead by the caller)."""
        if not self.client.eval(_TAKE_OVER, 1, self.key, dead_owner, self.token, self.ttl_ms):
            return False
        self._start()
        return True

    def holder(self) -> bytes | None:
        value = self.client.get(self.key)
        return value if isinstance(value, bytes) or value is None else str(value).encode()

    def remaining_s(self) -> float:
        """Seconds until the current holder's lock expires unless renewed (0 when unknown)."""
        try:
            ttl_ms = int(self.client.pttl(self.key))
        except redis.RedisError:
            return 0.0
        return max(0.0, ttl_ms / 1000)

    def _start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._beat, name=f"heartbeat {self.key}", daemon=True)
        self._thread.start()

    def _beat(self) -> None:
        while not self._stop.wait(self.ttl_ms / 1000 / self.beats):
            try:
                self.client.eval(_RENEW, 1, self.key, self.token, self.ttl_ms)
            except redis.RedisError:  # Redis away for a moment: the next beat tries again
                continue

    def release(self) -> None:
        """Stop the heartbeat and delete the lock if it is still ours (its TTL ends it otherwise)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        try:
            self.client.eval(_RELEASE, 1, self.key, self.token)
        except redis.RedisError:
            log.warning("lock %s: release failed; it expires within %d ms", self.key, self.ttl_ms)
