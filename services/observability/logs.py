"""Log lines a log pipeline can parse (``BFIELDS_LOG_FORMAT=json``): one JSON object a line.

Each line holds ``time`` (ISO 8601, UTC), ``level``, ``logger``, ``message`` and, where the code
that logs knows them, ``job_id``, ``tenant`` and ``stage`` (`log_context`, a context variable the
worker sets around a stage and the dispatcher around a send, so every line logged inside, the
library's included, carries them), ``trace_id`` and ``span_id`` of the current span when tracing
is on, and ``exception`` (the traceback) when there is one. Text stays the default: a person at a
terminal reads the handlers' own formats.

Why a formatter set on the handlers that exist (`use_json`) rather than a handler of our own:
uvicorn and Celery each install their handlers (uvicorn before the app is built, Celery's worker
on `after_setup_logger`), and the lines must keep going where the operator pointed them.
"""

from __future__ import annotations

import json
import logging
from contextvars import ContextVar
from datetime import UTC, datetime
from typing import Any

from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.observability import tracing

#: The job fields of the lines logged here (`log_context`).
_context: ContextVar[dict[str, str]] = ContextVar("bfields_log_context", default={})  # noqa: B039 (never mutated)

#: Loggers whose handlers uvicorn installs (propagation off for some of them).
_SERVER_LOGGERS = ("uvicorn", "uvicorn.error", "uvicorn.access")


class log_context:  # noqa: N801 (used as a function: ``with log_context(job_id=...)``)
    """Every line logged inside (in this thread or task) carries `fields` (None values left out).
    A class rather than a generator: entered once per stage and per dispatch, whatever the log
    format, so it costs what a context variable's set and reset cost."""

    __slots__ = ("fields", "token")

    def __init__(self, **fields: str | None) -> None:
        self.fields = {k: v for k, v in fields.items() if v is not None}

    def __enter__(self) -> None:
        self.token = _context.set({**_context.get(), **self.fields})

    def __exit__(self, *_: object) -> None:
        _context.reset(self.token)


def _trace_ids() -> dict[str, str]:
    if not tracing.enabled():
        return {}
    from opentelemetry import trace

    ctx = trace.get_current_span().get_span_context()
    if not ctx.is_valid:
        return {}
    return {"trace_id": f"{ctx.trace_id:032x}", "span_id": f"{ctx.span_id:016x}"}


class JsonFormatter(logging.Formatter):
    """A record as one JSON line (module docstring lists the fields)."""

    def format(self, record: logging.LogRecord) -> str:
        line: dict[str, Any] = {
            "time": datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds"),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
            **_context.get(),
            **_trace_ids(),
        }
        if record.exc_info:
            line["exception"] = self.formatException(record.exc_info)
        return json.dumps(line, default=str)


def use_json(logger: logging.Logger) -> None:
    """Give every handler of `logger` the JSON formatter."""
    formatter = JsonFormatter()
    for handler in logger.handlers:
        handler.setFormatter(formatter)


def configure(settings: ServiceSettings) -> None:
    """With ``log_format`` json: the handlers on the root logger and uvicorn's write JSON lines."""
    if settings.log_format != "json":
        return
    for logger in (logging.getLogger(), *(logging.getLogger(n) for n in _SERVER_LOGGERS)):
        use_json(logger)
