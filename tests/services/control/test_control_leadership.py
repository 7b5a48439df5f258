"""The control process's election on a real PostgreSQL: one leader per database, a standby leads as
soon as the leader's session ends (resigned, or its connection killed by the server as a dead
client's is), a leader that lost its session steps down at its next check, and a loop of the
control process starts working as soon as its replica leads and stops when it no longer does."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest
from sqlalchemy import Engine, text

from bayesian_fields_service.control.leadership import Leadership
from bayesian_fields_service.control.process import STANDBY_POLL_S, Loop
from tests.integration.fixtures.postgres import records_database


@pytest.fixture
def database() -> Iterator[Engine]:
    with records_database() as db:
        yield db


def _kill_sessions_holding(db: Engine, key: int) -> int:
    """Terminate the session holding advisory lock `key` in this database (what the server does to
    a dead client); advisory locks are per database, and other tests' leaders hold the same key in
    theirs."""
    high, low = (key >> 32) & 0xFFFFFFFF, key & 0xFFFFFFFF
    with db.connect() as conn:
        pids = conn.execute(
            text(
                "SELECT pid FROM pg_locks WHERE locktype = 'advisory' AND granted AND classid = :h AND objid = :l "
                "AND database = (SELECT oid FROM pg_database WHERE datname = current_database())"
            ),
            {"h": high, "l": low},
        ).scalars().all()  # fmt: skip
        for pid in pids:
            conn.execute(text("SELECT pg_terminate_backend(:p)"), {"p": pid})
        conn.commit()
    return len(pids)


def test_one_leader_and_a_standby_that_takes_over(database: Engine) -> None:
    first, second = Leadership(database), Leadership(database)
    assert first.check() and first.held
    assert not second.check() and not second.held
    assert first.check()  # a leader keeps its lead while its session lives
    first.resign()
    assert second.check() and second.held  # at its next check, no waiting on a lease
    assert not first.check()
    second.resign()


def test_a_leader_whose_session_the_server_ended_steps_down(database: Engine) -> None:
    leader, standby = Leadership(database), Leadership(database)
    assert leader.check()
    assert _kill_sessions_holding(database, leader.key) == 1
    assert standby.check()  # the lock went with the session
    assert not leader.check() and not leader.held  # it notices and stops acting
    standby.resign()


@pytest.mark.slow
def test_a_loop_works_only_while_its_replica_leads(database: Engine) -> None:
    leadership = Leadership(database)
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
