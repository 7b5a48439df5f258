"""A span exporter that appends finished spans to a file as JSON lines (``BFIELDS_TRACING=file:PATH``).

Why not the SDK's ConsoleSpanExporter pointed at a file: it writes indented, multi-line JSON, which
no line reader can split, and several processes (the API, the control process, each Celery pool
child) append to one file at once. Here each span is one line written with one ``write`` on a file
opened for appending, so the lines of concurrent processes never interleave within a line, and a
test or an operator reads the file with one ``json.loads`` a line. The line holds what a reader of
a trace needs, in OTLP's names: ids as hex, times in Unix nanoseconds, attributes, status, and the
process's service name.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from opentelemetry.sdk.trace import ReadableSpan
from opentelemetry.sdk.trace.export import SpanExporter, SpanExportResult


def span_record(span: ReadableSpan) -> dict[str, Any]:
    """One span as a JSON-ready dict (ids as lower-case hex, the parent's id or None)."""
    ctx = span.get_span_context()
    assert ctx is not None  # a finished SDK span always has its context
    parent = span.parent
    return {
        "name": span.name,
        "trace_id": f"{ctx.trace_id:032x}",
        "span_id": f"{ctx.span_id:016x}",
        "parent_id": f"{parent.span_id:016x}" if parent is not None else None,
        "kind": span.kind.name,
        "start_ns": span.start_time,
        "end_ns": span.end_time,
        "status": span.status.status_code.name,
        "attributes": dict(span.attributes or {}),
        "service": span.resource.attributes.get("service.name"),
        "pid": os.getpid(),
    }


class JsonLinesSpanExporter(SpanExporter):
    """Appends each exported span to `path` as one JSON line (module docstring says why)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def export(self, spans: Sequence[ReadableSpan]) -> SpanExportResult:
        lines = "".join(json.dumps(span_record(s), default=str) + "\n" for s in spans)
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, lines.encode())
        finally:
            os.close(fd)
        return SpanExportResult.SUCCESS

    def shutdown(self) -> None:
        """Nothing held open between exports."""
