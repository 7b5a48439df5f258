"""Who leads: the replica holding one PostgreSQL session advisory lock.

Why one lock for everything: the dispatcher, recovery, the orphan sweep and the callback sender
each used to elect itself (a Redis lease, two Redis locks, and a sender in every worker), so four
loops could be led from four places and a Redis restart dropped every lease. A session lock is
the database's: it is held exactly as long as the leader's connection lives, so a leader that is
killed (its socket closes) gives it up at once and a standby that asks every
`control_election_interval_s` leads within about that; a leader cut off from the database loses
its session when the server's TCP keepalives give up on it (set short here), and notices itself
at its next check, when it stops acting. Two leaders at once would still be harmless (the
dispatcher's ``SKIP LOCKED`` takes each job once; stages are locked and idempotent), only
wasteful.
"""

from __future__ import annotations

import logging
import threading

from sqlalchemy import Connection, Engine, create_engine, text
from sqlalchemy.exc import DBAPIError
from sqlalchemy.pool import NullPool

from bayesian_fields_service.records.locks import lock_key

log = logging.getLogger(__name__)

#: Server-side keepalives of the leader's session: the server drops a silent leader's session
#: (and with it the lock) after about idle + interval x count seconds.
_KEEPALIVES = {"tcp_keepalives_idle": 5, "tcp_keepalives_interval": 2, "tcp_keepalives_count": 3}


class Leadership:
    """The advisory lock of one deployment, held on a connection of its own (never returned to a
    pool). One per database (advisory locks are the database's): the jobs table is the queue, so
    a deployment is its database, and two deployments never share one."""

    def __init__(self, database: Engine) -> None:
        url = database.url.render_as_string(hide_password=False)
        self._engine = create_engine(url, poolclass=NullPool, connect_args={"connect_timeout": 5})
        self.key = lock_key("control-leader")
        self._conn: Connection | None = None
        self._held = threading.Event()

    @property
    def held(self) -> bool:
        """Whether this replica led at its last check (what the loops look at before each round)."""
        return self._held.is_set()

    def check(self) -> bool:
        """Keep or try to take the lead; True while this replica leads."""
        if self._conn is not None:
            try:
                self._conn.execute(text("SELECT 1"))
                self._conn.commit()
                return True
            except DBAPIError as exc:
                log.warning("lost the leader's session (%s); stepping down", exc)
                self._drop()
        try:
            conn = self._engine.connect()
        except DBAPIError as exc:
            log.warning("the records database is unreachable (%s)", exc)
            return False
        try:
            for name, value in _KEEPALIVES.items():
                conn.execute(text(f"SET {name} = {int(value)}"))
            if conn.execute(text("SELECT pg_try_advisory_lock(:k)"), {"k": self.key}).scalar_one():
                conn.commit()
                self._conn = conn
                self._held.set()
                return True
            conn.rollback()
        except DBAPIError as exc:
            log.warning("election failed (%s)", exc)
        conn.close()
        return False

    def _drop(self) -> None:
        self._held.clear()
        if self._conn is not None:
            try:
                self._conn.invalidate()  # closing the session is what releases the lock
                self._conn.close()
            except DBAPIError:
                pass
        self._conn = None

    def resign(self) -> None:
        """Give the lead up now (a clean shutdown: a standby takes over at its next check)."""
        self._drop()
