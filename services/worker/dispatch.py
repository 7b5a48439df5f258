"""Enqueue a job's stages as a Celery chain, by task name.

Kept apart from `tasks.py` so the API can enqueue without importing the pipeline (torch, models):
it only needs the task names and queues, which the stage table (`job.stage_table`) gives. The chain is perceive -> fuse on the GPU queue, then
cluster on the CPU queue; a resumed job sends only its unfinished stages.
"""

from __future__ import annotations

from collections.abc import Sequence

from celery import Celery, chain

from bayesian_fields_core.job.stage_table import stage as stage_spec


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
