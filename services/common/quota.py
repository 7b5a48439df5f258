"""The per-tenant admission bound as one Redis sorted set, changed only by atomic operations.

The set holds every unfinished job of the tenant (waiting in its fair-share queue, dispatched or
running); a submission is admitted while the set stays within BFIELDS_MAX_WAITING_JOBS_PER_TENANT
+ BFIELDS_MAX_ACTIVE_JOBS_PER_TENANT (`admission_limit`). How many of them run at once is bounded
apart, by the dispatcher (`common.fair_queue`).

Why not "count, then write": two API processes counting at the same moment both see room and
both write (100 simultaneous submissions at a quota of 16 used to accept 27). Here a Lua script
checks the set's size and adds the new job ids in one step, so at most `limit` ids are ever in
it. Members are job ids scored by the reservation time; a slot is taken before anything is
stored and given back on every terminal state (`JobStore.save`), on a failed submission, and by
the worker's recovery scan, which re-adds active jobs a Redis wipe forgot and drops members whose
job is gone or finished (see `repair`).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from typing import cast

import redis

#: KEYS[1] the tenant's set; ARGV[1] the limit, ARGV[2] the time, ARGV[3:] the new ids.
#: Returns {1, size after} when all ids were added, {0, size now} when they would not fit.
_RESERVE = """
local size = redis.call('ZCARD', KEYS[1])
local new = 0
for i = 3, #ARGV do
  if not redis.call('ZSCORE', KEYS[1], ARGV[i]) then new = new + 1 end
end
if size + new > tonumber(ARGV[1]) then return {0, size} end
for i = 3, #ARGV do redis.call('ZADD', KEYS[1], 'NX', ARGV[2], ARGV[i]) end
return {1, size + new}
"""


def admission_limit(max_waiting: int, max_dispatched: int) -> int:
    """Unfinished jobs a tenant may have: its waiting bound plus what may be dispatched."""
    return max_waiting + max_dispatched


def quota_key(tenant: str) -> str:
    return f"bf:active:{tenant}"


class TenantQuota:
    """Atomic reserve / release of active-job slots (one sorted set per tenant)."""

    def __init__(self, client: redis.Redis) -> None:
        self.client = client
        self._reserve = client.register_script(_RESERVE)

    def reserve(self, tenant: str, job_ids: Sequence[str], limit: int) -> tuple[bool, int]:
        """Take one slot per id, all or none. Returns (taken, active jobs now)."""
        ok, size = self._reserve(keys=[quota_key(tenant)], args=[limit, time.time(), *job_ids])
        return bool(ok), int(size)

    def release(self, tenant: str, job_ids: Iterable[str]) -> None:
        ids = list(job_ids)
        if ids:
            self.client.zrem(quota_key(tenant), *ids)

    def active(self, tenant: str) -> int:
        return int(self.client.zcard(quota_key(tenant)))

    def repair(self, tenant: str, active_ids: set[str], *, older_than_s: float) -> tuple[int, int]:
        """Make the set agree with the durable truth, the active rows of the jobs table.

        Ids of active rows are (re-)added; other ids are dropped once older than
        `older_than_s` (a younger one may be a reservation whose job is being written right now).
        Returns (added, dropped)."""
        key = quota_key(tenant)
        added = 0
        if active_ids:
            added = int(self.client.zadd(key, dict.fromkeys(active_ids, time.time()), nx=True) or 0)
        return added, self.drop_stale(key, active_ids, older_than_s=older_than_s)

    def drop_stale(self, key: str, active_ids: set[str], *, older_than_s: float) -> int:
        """Remove members of the sorted set `key` that are not in `active_ids` and older than
        `older_than_s` (scores are times). Returns how many went."""
        now = time.time()
        # withscores=True: (member, score) pairs
        members = cast(list[tuple[bytes, float]], self.client.zrange(key, 0, -1, withscores=True))
        stale = [
            m.decode() for m, score in members if m.decode() not in active_ids and score < now - older_than_s
        ]
        if stale:
            self.client.zrem(key, *stale)
        return len(stale)

    def tenants(self) -> list[str]:
        """Tenants that have a quota set in Redis."""
        return [k.decode().split(":", 2)[2] for k in self.client.scan_iter(match="bf:active:*", count=100)]
