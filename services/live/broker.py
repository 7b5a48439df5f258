"""The Celery side of dispatch: send a job's stages as a chain by task name, and read the queues.

Kept apart from `tasks.py` so the control process can send without importing the pipeline
(torch, models): it only needs the task names and queues, which the stage table
(`job.stage_table`) gives. The chain is perceive -> fuse on the GPU queue, then cluster on the
CPU queue; a resumed job sends only its unfinished stages. Submitted jobs wait in their tenant's
queue, the jobs table (`jobs.queue`), until the control process's dispatcher
(`control.dispatcher`) sends them here.
"""

from __future__ import annotations

from collections.abc import Sequence

import redis
from celery import Celery, chain
from kombu.exceptions import OperationalError

from bayesian_fields_core.job.stage_table import stage as stage_spec
from bayesian_fields_service.live import stage_wait  # noqa: F401 (stamps every stage message it sends)

#: What an unreachable broker raises: the broker is Redis (Celery's Redis transport), reached
#: directly (a queue's length) or through kombu (sending a stage). The API answers these 503
#: (`api.edge`), so no module outside this package needs to know kombu's exception classes.
BROKER_ERRORS: tuple[type[Exception], ...] = (redis.ConnectionError, redis.TimeoutError, OperationalError)


def queue_for(stage: str, gpu_queue: str, cpu_queue: str) -> str:
    """The queue of `stage`: its table row says "gpu" or "cpu"; the names come from the settings."""
    return gpu_queue if stage_spec(stage).queue == "gpu" else cpu_queue


def enqueue_stages(
    app: Celery, tenant: str, job_id: str, stages: Sequence[str], *, gpu_queue: str, cpu_queue: str
) -> None:
    """Send the chain of `stages` (in order) for one job. Arguments are plain JSON."""
    if not stages:
        return
    sigs = [
        app.signature(
            stage_spec(stage).task_name,
            args=(tenant, job_id),
            immutable=True,
            queue=queue_for(stage, gpu_queue, cpu_queue),
        )
        for stage in stages
    ]
    chain(*sigs).apply_async()


#: Celery's Redis transport keeps one list per priority step of a queue (priority 0 = the name).
PRIORITY_SUFFIXES = ("", "\x06\x163", "\x06\x166", "\x06\x169")


def queue_length(client: redis.Redis, queue: str) -> int:
    """Messages waiting in a Celery queue on the Redis broker (not those a worker reserved)."""
    pipe = client.pipeline()
    for sfx in PRIORITY_SUFFIXES:
        pipe.llen(queue + sfx)
    return int(sum(pipe.execute()))
