"""The worker's side of accounting (`jobs/usage.py`): measure a stage, put it on the job record
and in the tenant's usage ledger.

A `StageMeter` wraps the stage call: CPU-seconds are the process's CPU time over it (the pool
process runs one stage at a time, so all of it is this stage's, its helper threads included);
GPU-seconds are its wall time when the worker's device is CUDA, else 0; its peak GPU memory is
``torch.cuda.max_memory_allocated`` over the stage (the peak is reset at its start), 0 on a CPU
worker (`/metrics`: ``bfields_stage_gpu_memory_peak_bytes``). Only executions that end
(finished, failed, cancelled, timed out) are counted; one interrupted by a transient error and
retried is not (its retry is).
"""

from __future__ import annotations

import logging
import time
from types import TracebackType

from sqlalchemy import Engine

from bayesian_fields_core.job.store import Store
from bayesian_fields_service.jobs import usage
from bayesian_fields_service.jobs.durable_writes import until_landed
from bayesian_fields_service.jobs.model import JobRecord, utcnow
from bayesian_fields_service.storage.stores import tenant_store
from bayesian_fields_service.worker.scene_cache import list_input

log = logging.getLogger(__name__)


class StageMeter:
    """CPU and wall seconds of the ``with`` body (zeros when the body never started)."""

    def __init__(self, *, gpu: bool) -> None:
        self.gpu = gpu
        self.cpu_s = 0.0
        self.wall_s = 0.0
        self.gpu_peak_bytes = 0
        self._cpu0 = 0.0
        self._wall0 = 0.0

    def __enter__(self) -> StageMeter:
        if self.gpu:
            _reset_gpu_peak()
        self._cpu0, self._wall0 = time.process_time(), time.perf_counter()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.cpu_s = time.process_time() - self._cpu0
        self.wall_s = time.perf_counter() - self._wall0
        self.gpu_peak_bytes = _gpu_peak() if self.gpu else 0

    @property
    def gpu_s(self) -> float:
        return self.wall_s if self.gpu else 0.0


def _reset_gpu_peak() -> None:
    import torch  # the worker has it loaded already; imported here so the API never needs it

    if torch.cuda.is_available():
        torch.cuda.reset_peak_memory_stats()


def _gpu_peak() -> int:
    """Bytes of the most GPU memory the process's tensors held since the last reset (0 without CUDA)."""
    import torch

    return int(torch.cuda.max_memory_allocated()) if torch.cuda.is_available() else 0


def job_bytes(store: Store, record: JobRecord) -> int:
    """Bytes under the job's prefix (one LIST with sizes on S3)."""
    return sum(e.size for e in list_input(tenant_store(store, record.tenant), record.job_prefix))


def account_stage(
    store: Store,
    database: Engine,
    record: JobRecord,
    stage: str,
    meter: StageMeter,
    *,
    write_budget_s: float = 0.0,
) -> JobRecord:
    """`record` with this stage execution added to its usage (the caller saves it), and its ledger
    row, retried for `write_budget_s` while the database is unreachable (`durable_writes`; the row's
    entry id makes a repeated write count once). Accounting never fails a stage: a storage error,
    or a database error past the budget, is logged. (The job's end is ledgered by the jobs domain,
    in the transaction that makes it terminal.)"""
    try:
        size = job_bytes(store, record)
    except Exception as exc:  # the bucket is flaky: keep the last known size
        log.warning("job %s: size unknown (%s)", record.id, exc)
        size = record.usage.bytes_stored
    updated = record.model_copy(
        update={"usage": record.usage.add_stage(stage, meter.cpu_s, meter.gpu_s, size)}
    )
    try:
        until_landed(
            lambda: usage.record_stage(database, record.tenant, record.id, stage, record.stage_runs,
                                       meter.cpu_s, meter.gpu_s, utcnow()),
            budget_s=write_budget_s,
            what=f"the usage of stage {stage} of job {record.id}",
        )  # fmt: skip
    except Exception as exc:
        log.warning("job %s: usage of %s not recorded (%s)", record.id, stage, exc)
    return updated
