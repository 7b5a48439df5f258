"""What operators read of a running service: OpenTelemetry traces (`tracing`) and log lines as
text or JSON (`logs`), configured once per process from `ServiceSettings`."""
