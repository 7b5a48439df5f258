"""The Redis fixtures: the session's Redis is its own unless a shared one is named; a claimed
database is exclusive; a private server survives restarts."""

from __future__ import annotations

import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import redis

from tests.integration.fixtures.processes import REPO_ROOT, free_port
from tests.integration.fixtures.redis_server import (
    SHARED_REDIS_ENV,
    TEST_DBS,
    RedisServer,
    claim_shared_db,
    open_session_redis,
    ping,
)

MARKER = b"belongs to someone else"


def _write_markers(url_of_db0: str) -> None:
    """A key in every database 8-15 (and 0) of the Redis at `url_of_db0`, as a user's data."""
    for db in (0, *TEST_DBS):
        client = redis.Redis.from_url(url_of_db0.rsplit("/", 1)[0] + f"/{db}")
        client.set("user:data", MARKER)
        client.close()


def _markers_left(url_of_db0: str) -> dict[int, bool]:
    left = {}
    for db in (0, *TEST_DBS):
        client = redis.Redis.from_url(url_of_db0.rsplit("/", 1)[0] + f"/{db}")
        left[db] = client.get("user:data") == MARKER
        client.close()
    return left


def test_redis_url_is_usable_and_flushed(redis_url: str) -> None:
    client = redis.Redis.from_url(redis_url)
    try:
        assert client.ping()
        client.set("bfields:probe", "1")
        assert client.get("bfields:probe") == b"1"
    finally:
        client.delete("bfields:probe")
        client.close()


def test_session_redis_without_opt_in_is_private(private_redis: RedisServer, tmp_path: Path) -> None:
    """Another Redis holding data in databases 8-15 is never touched: the session starts its own."""
    other = private_redis.url()
    _write_markers(other)
    session = open_session_redis(tmp_path / "own", env={})
    try:
        assert session.server is not None and session.claimed is None
        assert f":{private_redis.port}/" not in session.url
        client = redis.Redis.from_url(session.url)
        client.set("bfields:probe", "1")
        client.flushdb()
        client.close()
    finally:
        session.close()
    assert all(_markers_left(other).values())


def test_session_redis_opt_in_claims_one_database(private_redis: RedisServer, tmp_path: Path) -> None:
    """Named by the opt-in, a shared Redis lends one database (flushed); the others keep their data."""
    shared = f"redis://127.0.0.1:{private_redis.port}"
    _write_markers(private_redis.url())
    session = open_session_redis(tmp_path / "unused", env={SHARED_REDIS_ENV: shared})
    try:
        assert session.server is None and session.claimed is not None
        assert session.url == f"{shared}/{session.claimed.db}"
        claimed = session.claimed.db
    finally:
        session.close()
    left = _markers_left(private_redis.url())
    assert left.pop(claimed) is False
    assert all(left.values())


def test_session_redis_opt_in_that_does_not_answer_says_so(tmp_path: Path) -> None:
    address = f"redis://127.0.0.1:{free_port()}"
    with pytest.raises(RuntimeError, match=f"{SHARED_REDIS_ENV}={address}: no Redis answers there"):
        open_session_redis(tmp_path, env={SHARED_REDIS_ENV: address})


def test_claimed_db_is_exclusive(private_redis: RedisServer, tmp_path: Path) -> None:
    shared = f"redis://127.0.0.1:{private_redis.port}"
    first = claim_shared_db(shared, lock_dir=tmp_path)
    assert first is not None
    second = claim_shared_db(shared, lock_dir=tmp_path)
    try:
        assert second is not None and second.db != first.db
    finally:
        first.release()
        if second is not None:
            second.release()


#: Run inside a network namespace of its own: a "machine's Redis" on 127.0.0.1:6379 there (not the
#: real one) holds a user's keys in databases 8-15 while a test session that uses `redis_url` runs.
_NAMESPACE_SCRIPT = textwrap.dedent(
    """
    set -eu
    ip link set lo up
    {redis} --port 6379 --bind 127.0.0.1 --save '' --appendonly no --dir {data} --daemonize yes \
        --logfile {data}/local.log
    {python} - <<'PY'
    import time, redis
    for _ in range(100):
        try:
            redis.Redis(port=6379).ping(); break
        except redis.ConnectionError:
            time.sleep(0.05)
    for db in range(8, 16):
        redis.Redis(port=6379, db=db).set("user:data", "kept")
    PY
    cd {repo}
    env -u {opt_in} {python} -m pytest -q -p no:cacheprovider --no-header \
        tests/integration/test_redis_fixtures.py::test_redis_url_is_usable_and_flushed
    {python} - <<'PY'
    import redis
    left = [db for db in range(8, 16) if redis.Redis(port=6379, db=db).get("user:data") == b"kept"]
    print("markers left in databases:", left)
    redis.Redis(port=6379).shutdown(nosave=True)
    PY
    """
)


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_test_session_leaves_the_local_redis_alone(tmp_path: Path) -> None:
    """The issue's check, end to end: a pytest session run beside a Redis on 127.0.0.1:6379 that
    holds keys in databases 8-15 leaves them all. The "local" Redis lives in a network namespace of
    the test's own (`unshare -rn`), so the machine's real Redis on 6379 is never touched."""
    redis_bin, unshare, ip = shutil.which("redis-server"), shutil.which("unshare"), shutil.which("ip")
    if redis_bin is None or unshare is None or ip is None:
        pytest.skip("needs redis-server, unshare and ip on PATH")
    if subprocess.run([unshare, "-rn", "true"], capture_output=True).returncode != 0:
        pytest.skip("unprivileged network namespaces are not allowed here (unshare -rn)")
    script = _NAMESPACE_SCRIPT.format(
        redis=redis_bin, data=tmp_path, python=sys.executable, repo=REPO_ROOT, opt_in=SHARED_REDIS_ENV
    )
    done = subprocess.run([unshare, "-rn", "bash", "-c", script], capture_output=True, text=True, timeout=110)
    out = done.stdout + done.stderr
    assert done.returncode == 0, out
    assert "1 passed" in out, out
    assert "markers left in databases: [8, 9, 10, 11, 12, 13, 14, 15]" in out, out


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
