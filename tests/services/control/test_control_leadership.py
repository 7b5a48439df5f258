"""The control process's election on a real PostgreSQL: one leader per database holding a lease
with a deadline; a standby takes it as soon as the leader resigns, or once the lease ran out when
the leader stopped renewing (killed, frozen, cut off); every take bumps the fencing token, and a
leader that lost the lease is refused by the fence in the very statements it makes (no stamp, no
requeue), whatever its own loops still believe; a loop works only while its replica leads."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest
from sqlalchemy import Engine, create_engine, func, insert, select

from bayesian_fields_service.control.leadership import Leadership
from bayesian_fields_service.control.process import STANDBY_POLL_S, Loop
from bayesian_fields_service.jobs.queue import JobQueue
from bayesian_fields_service.records.leases import (
    CONTROL_LEADER,
    Fence,
    LeaseLost,
    assert_lease,
    current_token,
)
from bayesian_fields_service.records.tables import control_leases, jobs
from tests.integration.fixtures.postgres import records_database

#: Short leases keep these tests quick; the production default is `control_lease_ttl_s`.
TTL_S = 1.5


@pytest.fixture
def database() -> Iterator[Engine]:
    with records_database() as db:
        yield db


def _waiting_job(db: Engine, job_id: str, tenant: str = "tenant-a") -> None:
    with db.begin() as conn:
        conn.execute(insert(jobs).values(
            id=job_id, tenant=tenant, scene_id="s_1", priority="interactive", tasks=["x"],
            parameters={}, model_profile="default",
        ))  # fmt: skip


def _dispatched_at(db: Engine, job_id: str) -> object:
    with db.connect() as conn:
        return conn.execute(select(jobs.c.dispatched_at).where(jobs.c.id == job_id)).scalar_one()


def test_one_leader_and_a_standby_that_takes_over_when_it_resigns(database: Engine) -> None:
    first, second = Leadership(database, lease_ttl_s=TTL_S), Leadership(database, lease_ttl_s=TTL_S)
    assert first.check() and first.held
    token = first.token
    assert not second.check() and not second.held
    assert first.check() and first.token == token  # a renewal keeps the token
    first.resign()
    assert not first.held
    assert second.check() and second.held  # at its next check, no waiting for the deadline
    assert second.token is not None and token is not None and second.token > token
    assert not first.check()
    second.resign()


def test_a_leader_that_stops_renewing_loses_the_lead_and_its_fence(database: Engine) -> None:
    """The freeze of a leader, without the signal: it simply does not renew past its deadline."""
    leader, standby = Leadership(database, lease_ttl_s=TTL_S), Leadership(database, lease_ttl_s=TTL_S)
    queue = JobQueue(database)
    assert leader.check()
    stale = leader.fence
    assert stale is not None
    assert not standby.check()  # the lease still runs
    time.sleep(TTL_S + 0.3)
    assert not leader.held and leader.fence is None  # it knows by its own clock, before asking
    assert standby.check() and standby.token == stale.token + 1
    _waiting_job(database, "j_fenced")
    with pytest.raises(LeaseLost):
        queue.take("tenant-a", stale)  # a round the old leader resumes stamps nothing
    assert _dispatched_at(database, "j_fenced") is None
    assert queue.take("tenant-a", standby.fence) is not None  # the new leader's does
    assert _dispatched_at(database, "j_fenced") is not None
    with pytest.raises(LeaseLost):
        queue.requeue("tenant-a", "j_fenced", stale)  # nor can it requeue
    assert _dispatched_at(database, "j_fenced") is not None
    assert not leader.check() and not leader.held  # and its next check finds the lease taken
    assert current_token(database, CONTROL_LEADER) == standby.token
    standby.resign()


def test_a_lease_that_expired_with_no_taker_is_taken_again_with_a_new_token(database: Engine) -> None:
    leader = Leadership(database, lease_ttl_s=TTL_S)
    assert leader.check()
    old = leader.token
    time.sleep(TTL_S + 0.3)
    assert leader.check() and leader.token == (old or 0) + 1  # what it fenced before is stale now
    with pytest.raises(LeaseLost):
        JobQueue(database).take("tenant-a", Fence(CONTROL_LEADER, old or 0))
    leader.resign()


def test_a_take_waits_for_a_fenced_transaction_in_flight(database: Engine) -> None:
    """A take of the lease and a fenced statement serialise on the lease row (FOR SHARE against
    the take's UPDATE): a stamp under a lease that a standby is taking right now either commits
    before the take or is refused, never after it."""
    leader = Leadership(database, lease_ttl_s=TTL_S)
    assert leader.check()
    fence = leader.fence
    assert fence is not None
    _waiting_job(database, "j_race")
    with database.connect() as conn, conn.begin():
        assert_lease(conn, fence)  # the leader's transaction holds the row FOR SHARE ...
        started = time.monotonic()
        result: list[bool] = []
        standby = Leadership(database, lease_ttl_s=TTL_S)
        taker = threading.Thread(target=lambda: result.append(standby.check()))
        time.sleep(TTL_S + 0.2)  # ... past the lease's deadline
        taker.start()
        taker.join(0.5)
        assert taker.is_alive()  # the take waits for the fenced transaction to end
    taker.join(5)
    assert result == [True] and time.monotonic() - started > TTL_S
    standby.resign()


def test_the_database_clock_decides_not_a_replica_without_a_database(database: Engine) -> None:
    """Renewals that fail (the database unreachable) keep the lead only until its own deadline."""
    leader = Leadership(database, lease_ttl_s=TTL_S)
    assert leader.check()
    # nothing listens on port 1: every renewal from now on fails as an unreachable database's does
    leader._engine = create_engine(database.url.set(port=1), connect_args={"connect_timeout": 1})  # noqa: SLF001
    assert leader.check() is True  # still within its lease
    time.sleep(TTL_S + 0.2)
    assert leader.check() is False and not leader.held


@pytest.mark.slow
def test_a_loop_works_only_while_its_replica_leads(database: Engine) -> None:
    leadership = Leadership(database, lease_ttl_s=TTL_S)
    stop = threading.Event()
    rounds: list[float] = []
    loop = Loop("probe", 0.05, lambda: rounds.append(time.monotonic()), lambda: leadership.held, stop)
    loop.start()
    try:
        time.sleep(3 * STANDBY_POLL_S)
        assert rounds == []  # a standby does nothing
        assert leadership.check()
        t0 = time.monotonic()
        deadline = t0 + 5
        while not rounds and time.monotonic() < deadline:
            time.sleep(0.01)
        assert rounds and rounds[0] - t0 <= STANDBY_POLL_S + 0.5  # leading, it starts at once
        leadership.resign()
        time.sleep(0.2)
        seen = len(rounds)
        time.sleep(3 * STANDBY_POLL_S)
        assert len(rounds) == seen  # and stops when it no longer leads
    finally:
        stop.set()
        leadership.resign()


def test_func_now_is_the_clock(database: Engine) -> None:
    """The lease's deadline is in the database's clock (`now()`), a few seconds ahead of it."""
    leader = Leadership(database, lease_ttl_s=TTL_S)
    assert leader.check()
    with database.connect() as conn:
        ahead = conn.execute(
            select(func.extract("epoch", control_leases.c.expires_at - func.now()))
        ).scalar_one()
    assert 0 < float(ahead) <= TTL_S
    leader.resign()
