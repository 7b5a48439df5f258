"""`bfields run --trace FILE`: the run's trace, one span a JSON line (the run, the model load,
the input checks and each stage with its frame / mask / Gaussian counts).

Why the project's own recorder and not the OpenTelemetry SDK: the library imports no tracing
client (the SDK would be a new dependency of every install of the library for one flag), and a
run in one process needs no context propagation, sampling or exporter plumbing, only spans with
ids, parents, times and attributes. The lines have the same fields as the service's span files
(``BFIELDS_TRACING=file:PATH``, `bayesian_fields_service.observability.span_files`): ``name``,
``trace_id`` (32 hex), ``span_id`` (16 hex), ``parent_id``, ``kind``, ``start_ns``, ``end_ns``
(Unix nanoseconds), ``status``, ``attributes``, ``service``, ``pid``, and the stage spans carry
the attributes the workers' do (`job.span_attributes`), so one reader serves both.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from bayesian_fields_core.job.span_attributes import stage_attributes

SERVICE = "bfields-cli"
"""The ``service`` of every span the CLI writes."""


class TraceFile:
    """One run's trace, written to `path` (truncated at the start) a span at a time as each ends,
    so a run that fails still leaves the spans that finished, the failing one marked ERROR."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.trace_id = secrets.token_hex(16)
        self._open: list[str] = []
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("")

    @contextlib.contextmanager
    def span(self, name: str, attributes: dict[str, Any] | None = None) -> Iterator[dict[str, Any]]:
        """A span under the innermost open one; yields its attributes, which the body may add to."""
        span_id = secrets.token_hex(8)
        record: dict[str, Any] = {
            "name": name,
            "trace_id": self.trace_id,
            "span_id": span_id,
            "parent_id": self._open[-1] if self._open else None,
            "kind": "INTERNAL",
            "start_ns": time.time_ns(),
            "end_ns": None,
            "status": "UNSET",
            "attributes": dict(attributes or {}),
            "service": SERVICE,
            "pid": os.getpid(),
        }
        self._open.append(span_id)
        try:
            yield record["attributes"]
        except BaseException as exc:
            record["status"] = "ERROR"
            record["attributes"]["exception.type"] = type(exc).__name__
            raise
        finally:
            self._open.pop()
            record["end_ns"] = time.time_ns()
            with self.path.open("a") as out:
                out.write(json.dumps(record, default=str) + "\n")

    def stage(self, name: str, run: Callable[[], dict[str, Any]]) -> dict[str, Any]:
        """`run_job`'s `around`: the stage in a span named ``stage <name>``, with its report's counts."""
        with self.span(f"stage {name}", {"bfields.stage": name}) as attributes:
            report = run()
            attributes.update(stage_attributes(name, report))
            return report
