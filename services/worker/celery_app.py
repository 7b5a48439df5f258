"""The Celery application: JSON only, late acks, one task in flight per process, gpu/cpu routing.

`make_celery(settings)` is used by the workers (`celery -A bayesian_fields_service.worker.celery_app worker -Q gpu`)
and by the API (which only sends tasks by name). Reliability settings, and why:
- ``task_acks_late`` + ``task_reject_on_worker_lost``: a task is acknowledged only after it ran, so
  a worker killed mid-stage leaves the message to be redelivered to another worker;
- ``worker_prefetch_multiplier=1``: a worker never hoards queued GPU stages it cannot start;
- ``visibility_timeout`` (Redis broker): how long an unacknowledged message waits before Redis
  hands it out again; it must exceed the longest stage (checked by the settings);
- JSON serializer and ``accept_content=['json']``: nothing is ever unpickled from the broker.
"""

from __future__ import annotations

import logging
from typing import Any

from celery import Celery
from celery.signals import after_setup_logger, after_setup_task_logger

from bayesian_fields_core.job.stage_table import STAGE_TABLE
from bayesian_fields_service import hooks
from bayesian_fields_service.config.settings import ServiceSettings, apply_log_level, get_settings
from bayesian_fields_service.observability import logs, tracing


def make_celery(settings: ServiceSettings, *, include_tasks: bool = False) -> Celery:
    """A Celery app bound to the settings' Redis; `include_tasks` registers the stage tasks."""
    apply_log_level(settings)
    if include_tasks:  # the worker's own app: its process's start
        hooks.install(settings)
        tracing.configure(settings, "worker")  # before the pool forks: its children inherit it
    app = Celery(
        "bfields",
        broker=settings.redis_url,
        include=["bayesian_fields_service.worker.tasks"] if include_tasks else [],
    )
    queues = {"gpu": settings.gpu_queue, "cpu": settings.cpu_queue}
    app.conf.update(
        task_serializer="json",
        result_serializer="json",
        accept_content=["json"],
        result_accept_content=["json"],
        task_ignore_result=True,
        result_backend=None,
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=settings.celery_prefetch_multiplier,
        broker_transport_options={"visibility_timeout": settings.celery_visibility_timeout_s},
        broker_connection_retry_on_startup=True,
        broker_connection_max_retries=None,
        task_default_queue=settings.cpu_queue,
        task_routes={spec.task_name: {"queue": queues[spec.queue]} for spec in STAGE_TABLE},
        task_soft_time_limit=settings.job_soft_time_limit_s,
        task_time_limit=settings.job_time_limit_s,
        worker_send_task_events=False,
        worker_hijack_root_logger=False,
    )
    app.conf.bfields_settings = settings
    return app


@after_setup_logger.connect
@after_setup_task_logger.connect
def _json_log_lines(logger: logging.Logger, **_: Any) -> None:
    """BFIELDS_LOG_FORMAT=json: the worker's handlers, which Celery installs once it starts, write
    JSON lines (`observability.logs`)."""
    if get_settings().log_format == "json":
        logs.use_json(logger)


app: Celery  # declared only: the module's __getattr__ below makes it on first access


def __getattr__(name: str) -> Celery:
    """``bayesian_fields_service.worker.celery_app.app``: the worker's app, built from the environment on first use."""
    if name == "app":
        global app
        app = make_celery(get_settings(), include_tasks=True)
        return app
    raise AttributeError(name)
