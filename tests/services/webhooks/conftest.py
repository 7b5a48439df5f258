"""What the delivery tests of this folder share: a records database of each module's own (its
control process leads there alone) and real HTTP receivers (`callback_receivers`), closed after
each test."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest
from sqlalchemy import Engine

from bayesian_fields_service.records.database import dispose_all, engine, migrate
from tests.integration.fixtures.postgres import create_database, drop_database
from tests.services.support.callback_receivers import Receiver


@pytest.fixture(scope="module")
def outbox_url() -> Iterator[str]:
    """A records database of this module's own."""
    url = create_database()
    migrate(url)
    yield url
    dispose_all()
    drop_database(url)


@pytest.fixture(scope="module")
def outbox(outbox_url: str) -> Engine:
    return engine(outbox_url)


@pytest.fixture
def receivers() -> Iterator[Callable[..., Receiver]]:
    """A maker of real receivers (`Receiver(behaviour, **kw)`), each closed after the test."""
    made: list[Receiver] = []

    def make(behaviour: str, **kw: object) -> Receiver:
        made.append(Receiver(behaviour, **kw))  # type: ignore[arg-type]
        return made[-1]

    yield make
    for r in made:
        r.close()
