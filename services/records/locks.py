"""Named locks held by a PostgreSQL session (`pg_advisory_lock`), for work that spans several
transactions and must not run twice at once: the requests carrying one Idempotency-Key, the
retries of one batch, the one completion of a scene (`scenes.lifecycle`; the scene's fate
itself is decided under its row's lock, `scenes.store`).

Why PostgreSQL and not Redis: a Redis lock outlives a Redis restart with persistence (and dies
with a restart without it), and one taken by an API process that is then killed stays until its
timeout: the client's retry waited two minutes. A session lock is the database's: it goes when
the session ends, whether the holder releases it, crashes or loses its connection, and Redis can
be lost without touching it.
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from functools import lru_cache

from sqlalchemy import Engine, create_engine, text
from sqlalchemy.exc import DBAPIError


class LockBusy(Exception):
    """The lock stayed held by another session for the whole wait."""


def lock_key(*names: str) -> int:
    """A signed 64-bit advisory-lock key from `names` (sha256: no two names share one by design)."""
    digest = hashlib.sha256("\0".join(names).encode()).digest()
    return int.from_bytes(digest[:8], "big", signed=True)


@contextmanager
def session_lock(database: Engine, *names: str, wait_s: float | None) -> Iterator[None]:
    """Hold the advisory lock of `names` for the ``with`` body (`session_locks` with one lock)."""
    with session_locks(database, [names], wait_s=wait_s):
        yield


#: How long a waiter sleeps between tries, at first and at most (it holds no connection meanwhile).
RETRY_S = (0.01, 0.2)


@lru_cache(maxsize=8)
def _lock_engine(url: str) -> Engine:
    """The pool lock sessions come from, apart from the work pool: a request holding a lock also
    needs a connection for its work, and if lock holders could take the whole work pool, each
    would wait for another's connection (100 concurrent submissions did, until the pool's 30 s
    timeout). Waiters hold no connection at all (`session_locks`)."""
    return create_engine(url, pool_pre_ping=True, pool_size=2, max_overflow=30, pool_timeout=60)


if hasattr(os, "register_at_fork"):  # a forked child builds its own pool, never uses the parent's
    os.register_at_fork(after_in_child=_lock_engine.cache_clear)


@contextmanager
def session_locks(
    database: Engine, locks: Sequence[Sequence[str]], *, wait_s: float | None
) -> Iterator[None]:
    """Hold the advisory lock of each name tuple in `locks` for the ``with`` body, on one session.
    All are taken at once or none (`pg_try_advisory_lock`; a try that finds one held gives back
    what it took and the session, sleeps, and tries again), so two requests naming the same locks
    never deadlock and a waiter holds no connection. Waits at most `wait_s` (None: one try);
    `LockBusy` past it. The session goes back to its pool only after unlocks that worked;
    otherwise it is closed, which releases the locks on the server."""
    keys = sorted({lock_key(*names) for names in locks})
    deadline = time.monotonic() + (wait_s or 0.0)
    pause = RETRY_S[0]
    pool = _lock_engine(database.url.render_as_string(hide_password=False))
    while True:
        conn = pool.connect()
        held: list[int] = []
        try:
            for key in keys:
                if not conn.execute(text("SELECT pg_try_advisory_lock(:key)"), {"key": key}).scalar_one():
                    break
                held.append(key)
            conn.commit()  # the locks are the session's; no transaction stays open while the body runs
            if len(held) == len(keys):
                yield
                return
        finally:
            try:
                conn.rollback()
                for key in reversed(held):
                    conn.execute(text("SELECT pg_advisory_unlock(:key)"), {"key": key})
                conn.commit()
            except DBAPIError:
                conn.invalidate()  # closing the session releases whatever it held
            conn.close()
        if time.monotonic() + pause > deadline:
            raise LockBusy(", ".join(" ".join(n) for n in locks))
        time.sleep(pause)
        pause = min(pause * 2, RETRY_S[1])
