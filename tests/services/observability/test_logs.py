"""JSON log lines (`observability.logs`): the fields of a line, the job's ids from `log_context`
inside and not outside it, and a traceback kept in one line."""

from __future__ import annotations

import io
import json
import logging
from collections.abc import Iterator

import pytest

from bayesian_fields_service.observability.logs import JsonFormatter, log_context


@pytest.fixture
def captured() -> Iterator[tuple[logging.Logger, io.StringIO]]:
    out = io.StringIO()
    handler = logging.StreamHandler(out)
    handler.setFormatter(JsonFormatter())
    logger = logging.getLogger("tests.observability.json")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False
    yield logger, out
    logger.removeHandler(handler)


def _lines(out: io.StringIO) -> list[dict]:
    return [json.loads(line) for line in out.getvalue().splitlines()]


def test_a_line_holds_the_job_fields_inside_its_context(captured: tuple[logging.Logger, io.StringIO]) -> None:
    logger, out = captured
    logger.info("before")
    with log_context(job_id="j_1", tenant="acme", stage=None):
        with log_context(stage="fuse"):
            logger.warning("stage %s of %s", "fuse", "j_1")
        logger.info("between")
    logger.info("after")
    before, inside, between, after = _lines(out)
    assert set(before) == {"time", "level", "logger", "message"} and before["level"] == "INFO"
    assert inside == {**inside, "level": "WARNING", "logger": "tests.observability.json",
                      "message": "stage fuse of j_1", "job_id": "j_1", "tenant": "acme", "stage": "fuse"}  # fmt: skip
    assert between["job_id"] == "j_1" and "stage" not in between
    assert "job_id" not in after
    assert before["time"].endswith("+00:00")  # ISO 8601, UTC


def test_an_exception_stays_in_its_line(captured: tuple[logging.Logger, io.StringIO]) -> None:
    logger, out = captured
    try:
        raise ValueError("bad\nvalue")
    except ValueError:
        logger.exception("stage crashed")
    (line,) = _lines(out)  # one line, however many the traceback has
    assert line["message"] == "stage crashed" and "ValueError: bad" in line["exception"]
