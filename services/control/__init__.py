"""The control process (`bfields-service control`): every background loop of the service, run by
one elected leader among its replicas (`leadership`): the fair-share dispatcher, orphan recovery,
the bucket's orphan sweep and the callback outbox sender (`process`)."""
