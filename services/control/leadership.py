"""Who leads: the replica holding the control lease (`records.leases`), renewed before its deadline.

Why one lease for everything: the dispatcher, recovery, the orphan sweep and the callback sender
each used to elect itself, so four loops could be led from four places. Why a lease with a
deadline and not a session advisory lock: a frozen leader (SIGSTOP, a pause of its VM) keeps its
session, and so kept the lock and the lead while it did nothing; a lease ends by itself
`lease_ttl_s` after the last renewal, and a standby that asks every `interval` takes it, which
bumps its fencing token. The leader renews at every check (every `control_election_interval_s`),
so a lease of a few intervals survives a slow statement or two.

`held` is this replica's own view, on its monotonic clock: true until `lease_ttl_s` after the
moment the last successful renewal was *sent*, which is never later than the row's deadline in the
database's clock. So a replica that wakes from a freeze knows at once that it no longer leads,
before it asks anyone; statements already under way are refused by the fence (`fence`), which
every statement made on the leader's behalf checks in its transaction.
"""

from __future__ import annotations

import logging
import os
import secrets
import socket
import threading
import time

from sqlalchemy import Engine, create_engine
from sqlalchemy.exc import DBAPIError
from sqlalchemy.pool import QueuePool

from bayesian_fields_service.records.leases import CONTROL_LEADER, Fence, release, take_or_renew

log = logging.getLogger(__name__)

#: A statement of the election gives up after this long (milliseconds): a check must never block
#: past the lease it is renewing (a partitioned database hangs, it does not refuse).
_STATEMENT_TIMEOUT_MS = 2000


class Leadership:
    """One replica's side of the control lease (module docstring). One lease per database: the
    jobs table is the queue, so a deployment is its database, and two deployments never share one."""

    def __init__(self, database: Engine, *, lease_ttl_s: float = 6.0, name: str = CONTROL_LEADER) -> None:
        url = database.url.render_as_string(hide_password=False)
        # An engine of its own, one connection: the election must not wait behind the loops' pool.
        self._engine = create_engine(
            url,
            poolclass=QueuePool,
            pool_size=1,
            max_overflow=0,
            pool_pre_ping=True,
            pool_timeout=_STATEMENT_TIMEOUT_MS / 1000,
            connect_args={"connect_timeout": 3, "options": f"-c statement_timeout={_STATEMENT_TIMEOUT_MS}"},
        )
        self.name = name
        self.lease_ttl_s = lease_ttl_s
        self.holder = f"{socket.gethostname()}:{os.getpid()}:{secrets.token_hex(4)}"
        self._lock = threading.Lock()
        self._token: int | None = None
        self._until = 0.0  # monotonic time at which this replica's view of its lead ends

    @property
    def held(self) -> bool:
        """Whether this replica leads now (what the loops look at before each round)."""
        with self._lock:
            return self._token is not None and time.monotonic() < self._until

    @property
    def fence(self) -> Fence | None:
        """The fence the leader's statements carry (None while this replica does not lead)."""
        with self._lock:
            if self._token is None or time.monotonic() >= self._until:
                return None
            return Fence(self.name, self._token)

    @property
    def token(self) -> int | None:
        """The token of the lease this replica holds, or held last (health bodies, tests)."""
        with self._lock:
            return self._token

    def check(self) -> bool:
        """Renew the lease, or try to take it; True while this replica leads."""
        sent_at = time.monotonic()
        with self._lock:
            token = self._token if time.monotonic() < self._until else None
        try:
            granted = take_or_renew(self._engine, self.name, self.holder, token, self.lease_ttl_s)
        except DBAPIError as exc:
            # Keep the lead until its own deadline: the lease may still be ours in the database,
            # and if it is not, the fence refuses whatever the loops try meanwhile.
            log.warning("the records database is unreachable for the election (%s)", exc)
            return self.held
        with self._lock:
            if granted is None:
                if self._token is not None:
                    log.warning("another control replica holds the lease; stepping down")
                self._token, self._until = None, 0.0
                return False
            if granted != token:
                log.warning("took the control lease (token %d)", granted)
            self._token, self._until = granted, sent_at + self.lease_ttl_s
            return True

    def resign(self) -> None:
        """Give the lead up now (a clean shutdown: a standby takes over at its next check)."""
        with self._lock:
            token, self._token, self._until = self._token, None, 0.0
        if token is not None:
            try:
                release(self._engine, Fence(self.name, token), self.holder)
            except DBAPIError as exc:  # it ends by itself at its deadline
                log.warning("could not release the control lease (%s)", exc)
        self._engine.dispose()
