"""Enqueue a job's stages as a Celery chain, by task name.

Kept apart from `tasks.py` so the API can enqueue without importing the pipeline (torch, models):
it only needs the task names and queues. The chain is perceive -> fuse on the GPU queue, then
cluster on the CPU queue; a resumed job sends only its unfinished stages.
"""

from __future__ import annotations

from collections.abc import Sequence

from celery import Celery, chain

STAGE_TASKS: dict[str, str] = {
    "perceive": "bfields.stage.perceive",
    "fuse": "bfields.stage.fuse",
    "cluster": "bfields.stage.cluster",
}
#: Which queue each stage runs on ("gpu" or "cpu"; the real names come from the settings).
STAGE_QUEUE_ROLE: dict[str, str] = {"perceive": "gpu", "fuse": "gpu", "cluster": "cpu"}


def queue_for(stage: str, gpu_queue: str, cpu_queue: str) -> str:
    return gpu_queue if STAGE_QUEUE_ROLE[stage] == "gpu" else cpu_queue


def enqueue_stages(
    app: Celery, tenant: str, job_id: str, stages: Sequence[str], *, gpu_queue: str, cpu_queue: str
) -> None:
    """Send the chain of `stages` (in order) for one job. Arguments are plain JSON."""
    if not stages:
        return
    sigs = [
        app.signature(
            STAGE_TASKS[stage],
            args=(tenant, job_id),
            immutable=True,
            queue=queue_for(stage, gpu_queue, cpu_queue),
        )
        for stage in stages
    ]
    chain(*sigs).apply_async()
