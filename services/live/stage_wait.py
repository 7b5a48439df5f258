"""When a stage's message was published, carried in the message, so the worker that starts it can
tell how long it waited in its queue (`bfields_stage_queue_wait_seconds`).

Why a header stamped at publication: Celery's messages carry no send time, and a stage's message
is published by different processes (the control process's dispatcher sends a job's first stage;
the worker that finishes a stage sends the next one of the chain; a retry re-sends its own).
A `before_task_publish` handler, connected wherever this module is imported (`live.broker`
imports it, so every process that sends stages has it), stamps each of them alike. A retry with
a countdown is due at its ``eta``, so its wait counts from then. The stamp is the sender's wall
clock: across hosts, their clock skew adds to (or hides) that much wait; NTP keeps it well under
the buckets' first bound in practice, and a negative difference is counted as 0.
"""

from __future__ import annotations

import time
from datetime import datetime
from typing import Any

from celery.signals import before_task_publish

from bayesian_fields_core.job.stage_table import STAGE_TABLE

#: The message header with the publisher's ``time.time()``.
PUBLISHED_AT = "bfields_published_at"
#: The stage tasks' names (the stage table's); no other task is stamped.
STAGE_TASKS = frozenset(spec.task_name for spec in STAGE_TABLE)


def _stamp(sender: str | None = None, headers: dict[str, Any] | None = None, **_: Any) -> None:
    if headers is not None and sender in STAGE_TASKS:
        headers[PUBLISHED_AT] = time.time()


before_task_publish.connect(_stamp, weak=False, dispatch_uid="bfields-stage-published-at")


def _header(request: Any, name: str) -> Any:
    """A message header as the task's request carries it (Celery puts custom headers on the
    request itself; older versions under ``request.headers``)."""
    value = getattr(request, name, None)
    if value is None:
        value = (getattr(request, "headers", None) or {}).get(name)
    return value


def waited_s(request: Any, now: float | None = None) -> float | None:
    """Seconds from the message's publication (or its ``eta``, when later) to `now`; None for a
    message without the stamp (sent by a process that predates it)."""
    published = _header(request, PUBLISHED_AT)
    if published is None:
        return None
    start = float(published)
    eta = _header(request, "eta")
    if eta:
        try:
            start = max(start, datetime.fromisoformat(str(eta)).timestamp())
        except ValueError:
            pass
    return max(0.0, (time.time() if now is None else now) - start)
