"""Per-tenant waiting queues in Redis and the atomic moves of the dispatcher that drains them.

Why not submit straight to Celery: the worker queues are FIFO, so one tenant's fleet of 1,000 jobs
would delay every other tenant by 1,000 jobs. Instead a submitted job waits in its tenant's queue
(one sorted set per tenant and priority class, ``interactive`` ahead of ``bulk``), and the leased
dispatcher (`bayesian_fields_service.worker.dispatch.Dispatcher`) releases jobs to the Celery
queues only while those queues are short, choosing the tenant by weighted fair share (stride
scheduling: each dispatch advances the tenant's *pass* by ``1 / weight``; the backlogged tenant
with the lowest pass goes next; a tenant that was idle rejoins at the current virtual time, so it
neither banks credit nor waits behind the others' backlog).

Every change is one Lua script, so a crash between two Redis calls never leaves a job in two
places or in none:
- `submit` adds ids to a waiting set unless the job already waits or was dispatched (idempotent:
  the API, a client's retry and the recovery scan may all submit the same job);
- `move` pops the head of one tenant's queue into its *dispatched* set (bounded by
  BFIELDS_MAX_ACTIVE_JOBS_PER_TENANT) and marks the job's live hash ``phase=dispatching``, only
  while the caller holds the dispatcher lease (fencing: a paused dispatcher whose lease expired
  moves nothing);
- `sent` turns ``dispatching`` into ``waiting`` once the Celery message is published; a job left
  ``dispatching`` (the dispatcher died in between) is found by the recovery scan and `requeue`d;
- `requeue` moves a job back to the front of its tenant's queue (recovery of a lost message);
- `remove` drops cancelled jobs from the waiting sets.

Keys (``ns`` is the GPU queue name, so two deployments on one Redis never dispatch each other's
jobs): ``bf:fq:<ns>:w:<tenant>:<priority>`` (zset, score = submission sequence),
``bf:fq:<ns>:tenants`` (tenants with waiting jobs), ``bf:fq:<ns>:pass`` / ``:vtime`` (stride
state), ``bf:fq:<ns>:lease``, ``bf:fq:<ns>:rate:<tenant>`` (recent dispatch times, for the
estimated start); ``bf:dispatched:<tenant>`` (zset of dispatched, unfinished jobs; given back on
every terminal state by `JobStore.release_slot`).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal, cast

import redis

Priority = Literal["interactive", "bulk"]
PRIORITIES: tuple[Priority, ...] = ("interactive", "bulk")

#: Seconds of dispatch history kept per tenant for the estimated start.
RATE_WINDOW_S = 600.0


def dispatched_key(tenant: str) -> str:
    return f"bf:dispatched:{tenant}"


def live_key(tenant: str, job_id: str) -> str:
    """The job's live hash (same key as `JobStore.live_key`)."""
    return f"bf:job:{tenant}:{job_id}"


# ARGV: ns, tenant, priority, score (nil = next sequence), ids...
_SUBMIT = """
local ns, t, prio = ARGV[1], ARGV[2], ARGV[3]
local base = 'bf:fq:' .. ns
local added = 0
for i = 5, #ARGV do
  local id = ARGV[i]
  if not redis.call('ZSCORE', 'bf:dispatched:' .. t, id)
     and not redis.call('ZSCORE', base .. ':w:' .. t .. ':interactive', id)
     and not redis.call('ZSCORE', base .. ':w:' .. t .. ':bulk', id) then
    local score = ARGV[4]
    if score == '' then score = redis.call('INCR', base .. ':seq') end
    redis.call('ZADD', base .. ':w:' .. t .. ':' .. prio, score, id)
    added = added + 1
  end
end
if added > 0 and redis.call('SADD', base .. ':tenants', t) == 1 then
  local vt = tonumber(redis.call('GET', base .. ':vtime') or '0')
  local p = tonumber(redis.call('HGET', base .. ':pass', t) or '0')
  if p < vt then redis.call('HSET', base .. ':pass', t, vt) end
end
return added
"""

# ARGV: ns, tenant, lease token, dispatch limit, now, quantum (1 / weight)
# Returns {-1} without the lease, {0} when nothing may move, {1, id, priority} after a move.
_MOVE = """
local ns, t = ARGV[1], ARGV[2]
local base = 'bf:fq:' .. ns
if redis.call('GET', base .. ':lease') ~= ARGV[3] then return {-1} end
local dkey = 'bf:dispatched:' .. t
if redis.call('ZCARD', dkey) >= tonumber(ARGV[4]) then return {0} end
for _, prio in ipairs({'interactive', 'bulk'}) do
  local wkey = base .. ':w:' .. t .. ':' .. prio
  local head = redis.call('ZRANGE', wkey, 0, 0)[1]
  if head then
    redis.call('ZREM', wkey, head)
    redis.call('ZADD', dkey, ARGV[5], head)
    redis.call('HSET', 'bf:job:' .. t .. ':' .. head, 'phase', 'dispatching', 'updated', ARGV[5])
    local p = tonumber(redis.call('HGET', base .. ':pass', t) or '0')
    redis.call('SET', base .. ':vtime', p)
    redis.call('HSET', base .. ':pass', t, p + tonumber(ARGV[6]))
    redis.call('ZADD', base .. ':rate:' .. t, ARGV[5], head)
    if redis.call('ZCARD', base .. ':w:' .. t .. ':interactive')
       + redis.call('ZCARD', base .. ':w:' .. t .. ':bulk') == 0 then
      redis.call('SREM', base .. ':tenants', t)
    end
    return {1, head, prio}
  end
end
redis.call('SREM', base .. ':tenants', t)
return {0}
"""

# KEYS[1] the live hash. Flip dispatching -> waiting (never overwrite a worker's 'active').
_SENT = """
if redis.call('HGET', KEYS[1], 'phase') == 'dispatching' then
  redis.call('HSET', KEYS[1], 'phase', 'waiting')
  return 1
end
return 0
"""

# ARGV: ns, tenant, priority, id. Back to the front of the tenant's queue (score 0).
_REQUEUE = """
local ns, t, prio, id = ARGV[1], ARGV[2], ARGV[3], ARGV[4]
local base = 'bf:fq:' .. ns
redis.call('ZREM', 'bf:dispatched:' .. t, id)
if redis.call('ZSCORE', base .. ':w:' .. t .. ':interactive', id)
   or redis.call('ZSCORE', base .. ':w:' .. t .. ':bulk', id) then return 0 end
redis.call('ZADD', base .. ':w:' .. t .. ':' .. prio, 0, id)
redis.call('HSET', 'bf:job:' .. t .. ':' .. id, 'phase', 'waiting', 'updated', ARGV[5])
if redis.call('SADD', base .. ':tenants', t) == 1 then
  local vt = tonumber(redis.call('GET', base .. ':vtime') or '0')
  local p = tonumber(redis.call('HGET', base .. ':pass', t) or '0')
  if p < vt then redis.call('HSET', base .. ':pass', t, vt) end
end
return 1
"""

# KEYS[1] the lease; ARGV: token, ttl ms. Take it when free, renew it when ours.
_LEASE = """
local cur = redis.call('GET', KEYS[1])
if cur == false then
  redis.call('SET', KEYS[1], ARGV[1], 'PX', ARGV[2]) return 1
elseif cur == ARGV[1] then
  redis.call('PEXPIRE', KEYS[1], ARGV[2]) return 1
end
return 0
"""


@dataclass
class TenantBacklog:
    """What the dispatcher needs to choose a tenant (one snapshot per choice)."""

    tenant: str
    interactive: int
    bulk: int
    dispatched: int
    pass_value: float


class FairQueue:
    """The waiting queues of one deployment (namespace `ns`, the GPU queue name)."""

    def __init__(self, client: redis.Redis, ns: str) -> None:
        self.client = client
        self.ns = ns
        self.base = f"bf:fq:{ns}"
        self._submit = client.register_script(_SUBMIT)
        self._move = client.register_script(_MOVE)
        self._sent = client.register_script(_SENT)
        self._requeue = client.register_script(_REQUEUE)
        self._lease = client.register_script(_LEASE)

    # ---- keys ----------------------------------------------------------------------------------
    def waiting_key(self, tenant: str, priority: str) -> str:
        return f"{self.base}:w:{tenant}:{priority}"

    @property
    def lease_key(self) -> str:
        return f"{self.base}:lease"

    # ---- submission side -----------------------------------------------------------------------
    def submit(self, tenant: str, priority: Priority, job_ids: Sequence[str]) -> int:
        """Append jobs to the tenant's queue (FIFO within a priority); ids already waiting or
        dispatched are left alone. Returns how many were added."""
        if not job_ids:
            return 0
        return int(self._submit(args=[self.ns, tenant, priority, "", *job_ids]))

    def contains(self, tenant: str, job_id: str) -> bool:
        """True while the job waits here or is dispatched (i.e. it was submitted)."""
        pipe = self.client.pipeline()
        pipe.zscore(dispatched_key(tenant), job_id)
        for prio in PRIORITIES:
            pipe.zscore(self.waiting_key(tenant, prio), job_id)
        return any(v is not None for v in pipe.execute())

    def remove(self, tenant: str, job_ids: Iterable[str]) -> None:
        ids = list(job_ids)
        if not ids:
            return
        pipe = self.client.pipeline()
        for prio in PRIORITIES:
            pipe.zrem(self.waiting_key(tenant, prio), *ids)
        pipe.execute()

    def requeue(self, tenant: str, priority: Priority, job_id: str) -> bool:
        """Put a dispatched job whose message was lost back at the front of its tenant's queue."""
        return bool(self._requeue(args=[self.ns, tenant, priority, job_id, time.time()]))

    # ---- reading -------------------------------------------------------------------------------
    def position(self, tenant: str, job_id: str) -> int | None:
        """1 for the tenant's next job, None when the job is not waiting."""
        pipe = self.client.pipeline()
        pipe.zrank(self.waiting_key(tenant, "interactive"), job_id)
        pipe.zrank(self.waiting_key(tenant, "bulk"), job_id)
        pipe.zcard(self.waiting_key(tenant, "interactive"))
        rank_i, rank_b, n_i = pipe.execute()
        if rank_i is not None:
            return int(rank_i) + 1
        if rank_b is not None:
            return int(n_i) + int(rank_b) + 1
        return None

    def dispatch_rate(self, tenant: str, now: float | None = None) -> float:
        """The tenant's jobs dispatched per second over the last `RATE_WINDOW_S`."""
        now = time.time() if now is None else now
        key = f"{self.base}:rate:{tenant}"
        self.client.zremrangebyscore(key, "-inf", now - RATE_WINDOW_S)
        members = cast(list[tuple[bytes, float]], self.client.zrange(key, 0, -1, withscores=True))
        if len(members) < 2:
            return 0.0
        span = max(now - members[0][1], 1.0)
        return len(members) / span

    def waiting(self, tenant: str) -> int:
        pipe = self.client.pipeline()
        for prio in PRIORITIES:
            pipe.zcard(self.waiting_key(tenant, prio))
        return int(sum(pipe.execute()))

    def dispatched(self, tenant: str) -> int:
        return int(self.client.zcard(dispatched_key(tenant)))

    def tenants(self) -> list[str]:
        return sorted(m.decode() for m in cast(set[bytes], self.client.smembers(f"{self.base}:tenants")))

    def waiting_by_tenant(self) -> dict[str, int]:
        """Waiting jobs per tenant that has any (for the Prometheus gauge)."""
        return {t: n for t in self.tenants() if (n := self.waiting(t))}

    def backlog(self) -> list[TenantBacklog]:
        tenants = self.tenants()
        if not tenants:
            return []
        pipe = self.client.pipeline()
        for t in tenants:
            pipe.zcard(self.waiting_key(t, "interactive"))
            pipe.zcard(self.waiting_key(t, "bulk"))
            pipe.zcard(dispatched_key(t))
        pipe.hmget(f"{self.base}:pass", tenants)
        values = pipe.execute()
        passes = values[-1]
        return [
            TenantBacklog(
                t, int(values[3 * i]), int(values[3 * i + 1]), int(values[3 * i + 2]), float(passes[i] or 0.0)
            )  # fmt: skip
            for i, t in enumerate(tenants)
        ]

    # ---- dispatcher side -----------------------------------------------------------------------
    def hold_lease(self, token: str, ttl_s: float) -> bool:
        """Take or renew the dispatcher lease (one dispatcher per namespace at a time)."""
        return bool(self._lease(keys=[self.lease_key], args=[token, int(ttl_s * 1000)]))

    def release_lease(self, token: str) -> None:
        if self.client.get(self.lease_key) == token.encode():
            self.client.delete(self.lease_key)

    def move(
        self, tenant: str, token: str, limit: int, weight: float
    ) -> tuple[int, str | None, Priority | None]:
        """Atomically move the tenant's next job to its dispatched set. Returns (1, id, priority)
        after a move, (0, None, None) when none may move, (-1, None, None) without the lease."""
        res = cast(
            list[bytes | int], self._move(args=[self.ns, tenant, token, limit, time.time(), 1.0 / weight])
        )
        code = int(res[0])
        if code != 1:
            return code, None, None
        job_id = res[1].decode() if isinstance(res[1], bytes) else str(res[1])
        prio = res[2].decode() if isinstance(res[2], bytes) else str(res[2])
        return 1, job_id, cast(Priority, prio)

    def sent(self, tenant: str, job_id: str) -> None:
        self._sent(keys=[live_key(tenant, job_id)])

    def release_dispatched(self, tenant: str, job_ids: Iterable[str]) -> None:
        ids = list(job_ids)
        if ids:
            self.client.zrem(dispatched_key(tenant), *ids)


def choose(backlog: list[TenantBacklog], limit: int, skip: set[str]) -> TenantBacklog | None:
    """The tenant to dispatch next: lowest pass among those with waiting jobs and room under the
    dispatch bound; on a tie, one with an interactive job first."""
    ready = [
        b for b in backlog if b.tenant not in skip and b.interactive + b.bulk > 0 and b.dispatched < limit
    ]
    if not ready:
        return None
    return min(ready, key=lambda b: (b.pass_value, 0 if b.interactive else 1, b.tenant))
