"""A throwaway Celery app that proves the worker fixture's mechanics independently of the service.

Configured like the real one where it matters to the fixture (JSON only, late acks, the broker
from BFIELDS_REDIS_URL).
"""

from __future__ import annotations

import os
import time

from celery import Celery

celery_app = Celery("mini", broker=os.environ["BFIELDS_REDIS_URL"], backend=os.environ["BFIELDS_REDIS_URL"])
celery_app.conf.update(
    task_serializer="json",
    accept_content=["json"],
    result_serializer="json",
    task_acks_late=True,
    worker_prefetch_multiplier=1,
)


@celery_app.task(name="mini.echo")
def echo(value: str) -> dict[str, str]:
    """Return the value with the worker's pid and HOME, so a test sees which process ran it."""
    return {"value": value, "pid": str(os.getpid()), "home": os.environ.get("HOME", "")}


@celery_app.task(name="mini.sleep")
def sleep(seconds: float) -> float:
    time.sleep(seconds)
    return seconds
