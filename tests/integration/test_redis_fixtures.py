"""The Redis fixtures: a claimed, flushed database and a private server that survives restarts."""

from __future__ import annotations

import redis

from tests.integration.fixtures.redis_server import RedisServer, claim_system_db, ping


def test_redis_url_is_usable_and_flushed(redis_url: str) -> None:
    client = redis.Redis.from_url(redis_url)
    try:
        assert client.ping()
        client.set("bfields:probe", "1")
        assert client.get("bfields:probe") == b"1"
    finally:
        client.delete("bfields:probe")
        client.close()


def test_claimed_db_is_exclusive() -> None:
    first = claim_system_db()
    if first is None:  # no system Redis here: nothing to claim
        return
    second = claim_system_db()
    try:
        assert second is None or second.db != first.db
    finally:
        first.release()
        if second is not None:
            second.release()


def test_private_redis_restart_keeps_data(private_redis: RedisServer) -> None:
    url = private_redis.url()
    client = redis.Redis.from_url(url)
    client.rpush("queue", "job-1", "job-2")
    client.close()

    private_redis.stop()
    assert not ping(url)
    private_redis.start()
    client = redis.Redis.from_url(url)
    assert client.lrange("queue", 0, -1) == [b"job-1", b"job-2"]

    client.rpush("queue", "job-3")
    client.close()
    private_redis.kill()  # a crash: appendfsync=always keeps job-3 too
    private_redis.start()
    client = redis.Redis.from_url(url)
    assert client.llen("queue") == 3
    client.close()
