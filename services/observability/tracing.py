"""OpenTelemetry tracing of a job through every process: one trace per job.

The submission request's server span (FastAPI's instrumentation) is the trace's root. Dispatch
happens later, in the control process, so the submission stores its W3C ``traceparent`` on the
job's row (`JobRecord.traceparent`); the dispatcher opens its ``dispatch`` span under it
(`job_span`), and Celery's instrumentation carries the context on to the workers in each
message's headers, where the task's span and the stage's span (`job_span`, with the stage's
counts) sit under it. SQL (SQLAlchemy), S3 (botocore) and Redis calls made inside those spans are
their children.

Off unless ``BFIELDS_TRACING`` names an exporter or ``OTEL_EXPORTER_OTLP_ENDPOINT`` is set
(`ServiceSettings.tracing_mode`). Off costs nothing measurable: the SDK and the instrumentations
are never imported, `job_span` hands back one shared do-nothing context, `current_traceparent`
returns None after one global read (bench/bench_tracing_off.py measures it).

Background work with no job (the control process's polls, a heartbeat thread's writes) would be a
trace per SQL or Redis call: a root span of kind CLIENT is not sampled (`_NoLoneClientCalls`);
every span under a sampled parent is.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bayesian_fields_service.config.settings import ServiceSettings

if TYPE_CHECKING:
    from opentelemetry.context import Context
    from opentelemetry.sdk.trace.sampling import SamplingResult
    from opentelemetry.trace import Link, SpanKind
    from opentelemetry.util.types import Attributes

#: The instrumentation scope of the service's own spans.
TRACER_NAME = "bayesian_fields_service"

#: Paths whose requests are not traced: probes and scrapes, every few seconds.
UNTRACED_URLS = "healthz,readyz,livez,metrics"

_on = False  # set once by `configure`; every hot path reads only this


def enabled() -> bool:
    """Whether this process exports spans."""
    return _on


class _Quiet:
    """The span handle `job_span` yields when tracing is off: takes attributes, keeps nothing."""

    def set_attributes(self, attributes: Mapping[str, Any]) -> None:
        """Nothing to record."""


_QUIET = _Quiet()
_QUIET_CONTEXT = contextlib.nullcontext(_QUIET)


def _exporter(mode: str) -> Any:
    if mode == "otlp":
        from opentelemetry.exporter.otlp.proto.http.trace_exporter import OTLPSpanExporter

        return OTLPSpanExporter()  # endpoint, headers, timeout: the standard OTEL_* variables
    if mode == "console":
        from opentelemetry.sdk.trace.export import ConsoleSpanExporter

        return ConsoleSpanExporter(formatter=lambda span: span.to_json(indent=None) + "\n")
    from bayesian_fields_service.observability.span_files import JsonLinesSpanExporter

    return JsonLinesSpanExporter(Path(mode.removeprefix("file:")))


def _sampler() -> Any:
    from opentelemetry.sdk.trace.sampling import Decision, ParentBased, Sampler, SamplingResult
    from opentelemetry.trace import SpanKind

    class _NoLoneClientCalls(Sampler):
        """Root spans: every one but a lone client call (module docstring says why)."""

        def should_sample(
            self,
            parent_context: Context | None,
            trace_id: int,
            name: str,
            kind: SpanKind | None = None,
            attributes: Attributes = None,
            links: Sequence[Link] | None = None,
            trace_state: Any = None,
        ) -> SamplingResult:
            keep = kind != SpanKind.CLIENT
            return SamplingResult(Decision.RECORD_AND_SAMPLE if keep else Decision.DROP, attributes)

        def get_description(self) -> str:
            return "NoLoneClientCalls"

    return ParentBased(root=_NoLoneClientCalls())


def configure(settings: ServiceSettings, service: str) -> bool:
    """Install the tracer provider and the library instrumentations in this process (`service`:
    api, control or worker, the default ``service.name`` suffix; OTEL_SERVICE_NAME wins). Idempotent;
    returns whether tracing is on."""
    global _on
    mode = settings.tracing_mode
    if mode == "off" or _on:
        return _on
    try:
        _install(mode, service)
    except ImportError as exc:  # asked for, not installed: a loud start, not a silent service
        raise RuntimeError(
            f"tracing is on ({mode!r}: BFIELDS_TRACING or OTEL_EXPORTER_OTLP_ENDPOINT) but {exc.name} is "
            "not installed: install the 'tracing' extra (pip install 'bayesian-fields[tracing]'), or "
            "set BFIELDS_TRACING=off"
        ) from exc
    _on = True
    return True


def _install(mode: str, service: str) -> None:
    """The tracer provider, its exporter and the library instrumentations (`configure`)."""
    from opentelemetry import trace
    from opentelemetry.instrumentation.botocore import BotocoreInstrumentor
    from opentelemetry.instrumentation.celery import CeleryInstrumentor
    from opentelemetry.instrumentation.redis import RedisInstrumentor
    from opentelemetry.sdk.resources import Resource
    from opentelemetry.sdk.trace import TracerProvider
    from opentelemetry.sdk.trace.export import BatchSpanProcessor, SimpleSpanProcessor

    resource = Resource.create()
    if str(resource.attributes.get("service.name", "")).startswith("unknown_service"):
        resource = resource.merge(Resource({"service.name": f"bfields-{service}"}))
    provider = TracerProvider(resource=resource, sampler=_sampler())
    exporter = _exporter(mode)
    # OTLP batches in a thread (the SDK restarts it in a forked pool child); a file or the console
    # is written at once, so a process that is killed loses no finished span.
    processor = BatchSpanProcessor(exporter) if mode == "otlp" else SimpleSpanProcessor(exporter)
    provider.add_span_processor(processor)
    trace.set_tracer_provider(provider)
    BotocoreInstrumentor().instrument()
    RedisInstrumentor().instrument()
    CeleryInstrumentor().instrument()


class _FreshContext:
    """Each request starts from an empty context (the instrumentation then reads the client's
    traceparent header, if any). Without it, a request that arrives while the previous one on the
    same keep-alive connection is finishing runs in a copy of that one's context (uvicorn starts
    it from the previous response's last send), and its span became a child of the previous
    request's: measured here, every poll after a scene upload sat in the upload's trace."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        from opentelemetry import context

        token = context.attach(context.Context())
        try:
            await self.app(scope, receive, send)
        finally:
            context.detach(token)


def instrument_app(app: Any) -> None:
    """Server spans for every request of a FastAPI app (probes and scrapes left out), each request
    the root of its own trace unless the client sent a traceparent (`_FreshContext`)."""
    if not _on:
        return
    from opentelemetry.instrumentation.fastapi import FastAPIInstrumentor

    FastAPIInstrumentor.instrument_app(app, excluded_urls=UNTRACED_URLS, exclude_spans=["receive", "send"])
    build = app.build_middleware_stack  # the instrumented one: the request's span outermost

    def build_fresh() -> Any:
        return _FreshContext(build())

    app.build_middleware_stack = build_fresh


_engines: list[Any] = []  # every engine of this process so far (`instrument_engine` says why)


def instrument_engine(engine: Any) -> None:
    """Spans for the statements of a SQLAlchemy engine. The instrumentation instruments once per
    process, so each new engine (another database URL, a forked pool child's own) re-instruments
    the whole list; `skip_dep_check`: it declares sqlalchemy < 2.1, and its cursor events are the
    same in 2.1 (the real-stack trace test sees the statements)."""
    if not _on:
        return
    from opentelemetry.instrumentation.sqlalchemy import SQLAlchemyInstrumentor

    _engines.append(engine)
    instrumentor = SQLAlchemyInstrumentor()
    if instrumentor.is_instrumented_by_opentelemetry:
        instrumentor.uninstrument()
    instrumentor.instrument(engines=list(_engines), enable_commenter=False, skip_dep_check=True)


def current_traceparent() -> str | None:
    """The W3C ``traceparent`` of the span current here (what a job's row keeps), or None."""
    if not _on:
        return None
    from opentelemetry.propagate import inject

    carrier: dict[str, str] = {}
    inject(carrier)
    return carrier.get("traceparent")


def annotate(attributes: Mapping[str, Any]) -> None:
    """Add attributes to the span current here (the request's, the task's)."""
    if not _on:
        return
    from opentelemetry import trace

    trace.get_current_span().set_attributes(dict(attributes))


@contextlib.contextmanager
def _span(name: str, traceparent: str | None, attributes: Mapping[str, Any]) -> Iterator[Any]:
    from opentelemetry import trace
    from opentelemetry.propagate import extract

    parent = extract({"traceparent": traceparent}) if traceparent else None
    tracer = trace.get_tracer(TRACER_NAME)
    with tracer.start_as_current_span(name, context=parent, attributes=dict(attributes)) as span:
        yield span


def job_span(
    name: str, attributes: Mapping[str, Any], traceparent: str | None = None
) -> contextlib.AbstractContextManager[Any]:
    """A span of the service's own (``dispatch``, ``stage perceive``) under the current span, or
    under the job's stored `traceparent` when given; its handle takes more attributes
    (``set_attributes``). Off: one shared do-nothing context."""
    if not _on:
        return _QUIET_CONTEXT
    return _span(name, traceparent, attributes)
