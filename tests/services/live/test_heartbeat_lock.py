"""The one heartbeat lock of the workers (stage locks, single flight), on a real Redis: renewed
while its holder lives (and put back after Redis lost it), expired when the holder stops beating,
never released or renewed by anyone but its owner, taken over only from the owner named."""

from __future__ import annotations

import time

import redis

from bayesian_fields_service.live import heartbeat_lock
from bayesian_fields_service.live.heartbeat_lock import HeartbeatLock
from tests.integration.fixtures.redis_server import RedisServer

TTL_S = 0.6


def test_a_held_lock_outlives_its_ttl_and_comes_back_after_a_flush(private_redis: RedisServer) -> None:
    client = redis.Redis.from_url(private_redis.url())
    lock = HeartbeatLock(client, "bf:test:hb", "owner-a", TTL_S)
    assert lock.acquire()
    try:
        assert not HeartbeatLock(client, "bf:test:hb", "owner-b", TTL_S).acquire()
        time.sleep(3 * TTL_S)
        assert client.get("bf:test:hb") == b"owner-a"  # renewed past three TTLs
        client.flushall()  # Redis lost it: the next beat puts it back
        time.sleep(TTL_S)
        assert client.get("bf:test:hb") == b"owner-a"
    finally:
        lock.release()
    assert client.get("bf:test:hb") is None


def test_a_holder_that_stops_beating_loses_the_lock_within_its_ttl(private_redis: RedisServer) -> None:
    client = redis.Redis.from_url(private_redis.url())
    dead = HeartbeatLock(client, "bf:test:dead", "owner-a", TTL_S)
    assert dead.acquire()
    dead._stop.set()  # what a SIGKILL does to the heartbeat thread
    started = time.monotonic()
    heir = HeartbeatLock(client, "bf:test:dead", "owner-b", TTL_S)
    while not heir.acquire():
        assert time.monotonic() - started < 2 * TTL_S + 0.5, "the dead holder's lock did not expire"
        time.sleep(0.02)
    heir.release()


def test_release_and_renewal_never_touch_another_owners_lock(private_redis: RedisServer) -> None:
    """The old release was GET then DEL: a lock that expired in between and was taken by another
    worker got deleted. Now a late release (and a late heartbeat) of the first owner change nothing."""
    client = redis.Redis.from_url(private_redis.url())
    first = HeartbeatLock(client, "bf:test:own", "owner-a", TTL_S)
    assert first.acquire()
    first._stop.set()
    client.set("bf:test:own", "owner-b", px=int(TTL_S * 1000))  # expired and taken over meanwhile
    first.release()
    assert client.get("bf:test:own") == b"owner-b"
    # a heartbeat of the first owner that comes late changes nothing either
    assert client.eval(heartbeat_lock._RENEW, 1, "bf:test:own", "owner-a", 1000) == 0
    assert client.get("bf:test:own") == b"owner-b"


def test_take_over_only_from_the_owner_named(private_redis: RedisServer) -> None:
    client = redis.Redis.from_url(private_redis.url())
    client.set("bf:test:steal", "dead-owner", px=60_000)
    heir = HeartbeatLock(client, "bf:test:steal", "heir", TTL_S)
    assert not heir.take_over(b"someone-else")
    assert heir.take_over(b"dead-owner")
    try:
        assert client.get("bf:test:steal") == b"heir" and 0 < heir.remaining_s() <= TTL_S
    finally:
        heir.release()
