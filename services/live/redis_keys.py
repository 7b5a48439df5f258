"""Every Redis key the service reads or writes, in one place.

Why one module: a key written in one file and read in another (a live hash, a cancel flag that
workers poll) is an interface; when each side spelled it, the job's live key ended up
defined twice and written a third time inside a Lua script. What Redis holds is disposable:
live progress, cancel flags (a cache of the row's), single-flight locks and metrics histograms (the
tests' pause points keep their keys in their own plugin, tests/services/support/service_hooks.py);
the records (jobs, their queue, batches, scenes, callbacks, usage) are PostgreSQL's. The
Celery broker's own keys (one list per queue and priority, named after the queue) are Celery's.
"""

from __future__ import annotations


def live_job(tenant: str, job_id: str) -> str:
    """Hash: the job's live state, stage, progress and phase ('waiting' / 'active')."""
    return f"bf:job:{tenant}:{job_id}"


def cancel_flag(tenant: str, job_id: str) -> str:
    """A set key while a cancel was accepted: workers look between frames."""
    return f"bf:cancel:{tenant}:{job_id}"


def flight_lock(tenant: str, key: str) -> str:
    """The single-flight lock of one shared computation (one perception per scene)."""
    return f"bf:flight:{tenant}:{key}"


#: Histograms (hashes of bucket counters), formatted with ``stage=``, ``outcome=`` or ``tenant=``.
STAGE_HISTOGRAM = "bf:metrics:stage:{stage}"
JOB_HISTOGRAM = "bf:metrics:job:{outcome}"
QUEUE_WAIT_HISTOGRAM = "bf:metrics:queue_wait:{tenant}"
STAGE_QUEUE_WAIT_HISTOGRAM = "bf:metrics:stage_queue_wait:{stage}"
STAGE_GPU_MEMORY_HISTOGRAM = "bf:metrics:stage_gpu_memory:{stage}"
#: Hash of counters per stage: ``cpu_s`` and ``gpu_s`` (seconds of finished stage executions).
STAGE_USAGE = "bf:metrics:stage_usage:{stage}"
