"""Tracing in one process: off, it imports no SDK and its helpers do nothing; on with a file, a
span started from a job's stored traceparent joins that trace, nested spans resolve their
parents, and each span is one JSON line (`span_files`). The process tests run in a subprocess:
the tracer provider is process-global."""

from __future__ import annotations

import gzip
import http.server
import json
import os
import subprocess
import sys
import textwrap
import threading
from pathlib import Path
from typing import Any

import pytest
from opentelemetry.proto.collector.trace.v1.trace_service_pb2 import (
    ExportTraceServiceRequest,
    ExportTraceServiceResponse,
)

from bayesian_fields_service.observability import tracing

ROOT = Path(__file__).resolve().parents[3]


def _python(code: str, env: dict[str, str]) -> str:
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("BFIELDS_", "OTEL_"))}
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env={**clean, "PYTHONPATH": str(ROOT), **env},
                          capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


def test_off_the_helpers_do_nothing() -> None:
    assert not tracing.enabled()
    assert tracing.current_traceparent() is None
    first = tracing.job_span("dispatch", {"bfields.job_id": "j_1"}, "00-" + "1" * 32 + "-" + "2" * 16 + "-01")
    assert first is tracing.job_span("stage fuse", {})  # one shared do-nothing context
    with first as handle:
        handle.set_attributes({"bfields.frames": 4})
    tracing.annotate({"bfields.job_id": "j_1"})


@pytest.mark.slow
def test_off_no_sdk_is_imported() -> None:
    out = _python(
        """
        import sys
        from bayesian_fields_service.config.settings import get_settings
        from bayesian_fields_service.observability import tracing
        from bayesian_fields_service.records.database import engine
        assert tracing.configure(get_settings(), "api") is False
        with tracing.job_span("dispatch", {}):
            pass
        print(sorted(m for m in sys.modules if m.startswith("opentelemetry.sdk")
                     or m.startswith("opentelemetry.instrumentation")))
        """,
        {},
    )
    assert out.strip() == "[]"


@pytest.mark.slow
def test_a_span_from_a_stored_traceparent_joins_its_trace(tmp_path: Path) -> None:
    spans = tmp_path / "spans.jsonl"
    parent = "00-" + "ab" * 16 + "-" + "cd" * 8 + "-01"
    out = _python(
        f"""
        from bayesian_fields_service.config.settings import get_settings
        from bayesian_fields_service.observability import tracing
        assert tracing.configure(get_settings(), "control") is True
        with tracing.job_span("dispatch", {{"bfields.job_id": "j_1"}}, "{parent}") as span:
            span.set_attributes({{"bfields.stages": "perceive,fuse,cluster"}})
            with tracing.job_span("stage perceive", {{}}) as inner:
                inner.set_attributes({{"bfields.frames": 4}})
                print(tracing.current_traceparent())
        """,
        {"BFIELDS_TRACING": f"file:{spans}"},
    )
    inner, outer = (json.loads(line) for line in spans.read_text().splitlines())  # written as each ends
    assert outer["name"] == "dispatch" and inner["name"] == "stage perceive"
    assert outer["trace_id"] == inner["trace_id"] == "ab" * 16
    assert outer["parent_id"] == "cd" * 8 and inner["parent_id"] == outer["span_id"]
    assert outer["attributes"] == {"bfields.job_id": "j_1", "bfields.stages": "perceive,fuse,cluster"}
    assert inner["attributes"] == {"bfields.frames": 4} and outer["service"] == "bfields-control"
    assert out.strip() == f"00-{'ab' * 16}-{inner['span_id']}-01"


class _OtlpReceiver(http.server.BaseHTTPRequestHandler):
    """An OTLP/HTTP trace endpoint: keeps each request's path, headers and decoded body."""

    received: list[tuple[str, str, ExportTraceServiceRequest]] = []

    def do_POST(self) -> None:  # noqa: N802 (http.server's name)
        body = self.rfile.read(int(self.headers["Content-Length"]))
        if self.headers.get("Content-Encoding") == "gzip":
            body = gzip.decompress(body)
        request = ExportTraceServiceRequest()
        request.ParseFromString(body)
        self.received.append((self.path, self.headers.get("Content-Type", ""), request))
        self.send_response(200)
        self.send_header("Content-Type", "application/x-protobuf")
        self.end_headers()
        self.wfile.write(ExportTraceServiceResponse().SerializeToString())

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (the base class's name)
        """Quiet: the test reads what arrived."""


@pytest.mark.slow
def test_the_standard_otlp_endpoint_receives_the_job_spans_over_http() -> None:
    """`OTEL_EXPORTER_OTLP_ENDPOINT` alone turns tracing on and the SDK's OTLP/HTTP exporter posts
    the spans (batched, flushed at exit) to a real HTTP receiver, as protobuf, with the trace kept."""
    _OtlpReceiver.received = []
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _OtlpReceiver)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    parent = "00-" + "ef" * 16 + "-" + "12" * 8 + "-01"
    try:
        _python(
            f"""
            from bayesian_fields_service.config.settings import get_settings
            from bayesian_fields_service.observability import tracing
            assert tracing.configure(get_settings(), "worker") is True
            with tracing.job_span("stage fuse", {{"bfields.job_id": "j_9"}}, "{parent}") as span:
                span.set_attributes({{"bfields.masks": 77}})
            """,
            {"OTEL_EXPORTER_OTLP_ENDPOINT": f"http://127.0.0.1:{server.server_address[1]}"},
        )
    finally:
        server.shutdown()
    assert [(path, kind) for path, kind, _ in _OtlpReceiver.received] == [
        ("/v1/traces", "application/x-protobuf")
    ]
    (resource_spans,) = _OtlpReceiver.received[0][2].resource_spans
    service = {a.key: a.value.string_value for a in resource_spans.resource.attributes}["service.name"]
    (span,) = [s for scope in resource_spans.scope_spans for s in scope.spans]
    assert service == "bfields-worker" and span.name == "stage fuse"
    assert span.trace_id.hex() == "ef" * 16 and span.parent_span_id.hex() == "12" * 8
    attributes = {a.key: a.value for a in span.attributes}
    assert attributes["bfields.job_id"].string_value == "j_9" and attributes["bfields.masks"].int_value == 77
