"""The retry rule of the writes that must land (`jobs.durable_writes`): repeated while the records
database is unreachable, within the budget; never for an error that is not an outage."""

from __future__ import annotations

import time

import pytest
from sqlalchemy import create_engine, text
from sqlalchemy.exc import IntegrityError, OperationalError

from bayesian_fields_service.jobs.durable_writes import unreachable, until_landed


def _outage() -> OperationalError:
    """A real unreachable-database error, from a real connection attempt to a closed port."""
    engine = create_engine(
        "postgresql+psycopg://postgres@127.0.0.1:1/postgres", connect_args={"connect_timeout": 1}
    )
    try:
        with engine.connect() as conn:
            conn.execute(text("SELECT 1"))
    except OperationalError as exc:
        return exc
    finally:
        engine.dispose()
    raise AssertionError("something answered on port 1")


def test_a_write_is_repeated_until_the_database_answers() -> None:
    outage = _outage()
    assert unreachable(outage)
    tries: list[float] = []

    def write() -> str:
        tries.append(time.monotonic())
        if len(tries) < 3:
            raise outage
        return "landed"

    assert until_landed(write, budget_s=10, what="a test write") == "landed"
    assert len(tries) == 3
    assert tries[2] - tries[1] > tries[1] - tries[0] >= 0.4  # backing off


def test_past_the_budget_the_outage_propagates() -> None:
    outage = _outage()
    t0 = time.monotonic()
    with pytest.raises(OperationalError):
        until_landed(lambda: (_ for _ in ()).throw(outage), budget_s=1.2, what="a test write")
    assert time.monotonic() - t0 < 2.5


def test_an_error_that_is_not_an_outage_is_not_retried() -> None:
    tries = []

    def write() -> None:
        tries.append(1)
        raise IntegrityError("INSERT", {}, Exception("duplicate key"))

    with pytest.raises(IntegrityError):
        until_landed(write, budget_s=10, what="a test write")
    assert tries == [1]
    assert not unreachable(ValueError("no"))
