"""Settle the dispatched jobs no worker runs: finish, wait, requeue or fail each, by rule, from its row.

A waiting job cannot be lost: it is a row (`common.job_queue`). What can be lost is a dispatched
job's stage message (Redis restarted without its data, a worker took the message and died, the
dispatcher died between its stamp and its send) or the write that would have ended it (the
records database unreachable for longer than the worker's retries). Whether a worker runs a job
is read from its row: the worker that runs a stage claims the job there and beats `heartbeat_at`
every quarter of `stage_lock_ttl_s` (`records.job_heartbeats`). One statement reads every
dispatched, unfinished job; each with no fresh heartbeat is settled by one rule:

- **finish**: every stage is done (its artifacts and stage reports are on the row and in the
  bucket; only the final write was lost): it is marked succeeded, with its callback and usage
  rows in that same transaction, once (`jobs.lifecycle.finish`). Before, such a job was requeued
  and the dispatcher had no stage left to send, forever;
- **wait**: no worker claims it, its live progress says its next message was sent ('waiting'),
  and it has been idle for less than `message_wait_s`: the message waits in a worker queue
  (queues can be long between two stages). Nothing reads the broker's own keys: the live hash is
  this service's progress display, and when Redis lost it (a restart) the job is a suspect at once;
- **requeue**: otherwise (a claim gone silent: a worker died mid-stage, or after taking the
  message; no live state: Redis lost the message; a message idle past `message_wait_s`), after it
  has looked orphaned for `recovery_grace_s` on two scans: its dispatch stamp is cleared, so it is
  the front of its tenant's queue, and `recoveries` counts the move;
- **fail**: a job already requeued `max_recoveries` times fails with that reason instead.

A duplicate that slips through is harmless: stages are idempotent (finished stages are skipped)
and a job is claimed by one delivery at a time, so the cost is time, never a wrong result. A
requeue is fenced by the leader's lease; a finish or a failure is right whoever writes it (a
terminal state is written once).

Run by the control process's leader only, so the first-seen times of suspects live in its memory
(a new leader starts them afresh, which only delays a requeue by one grace period).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from bayesian_fields_core.job.stage_table import STAGES
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.jobs import lifecycle
from bayesian_fields_service.jobs.model import JobState
from bayesian_fields_service.jobs.store import JobStore
from bayesian_fields_service.records.job_heartbeats import DispatchedJob, dispatched_jobs
from bayesian_fields_service.records.leases import Fence, LeaseLost

log = logging.getLogger(__name__)


@dataclass
class Recovery:
    """The scan (module docstring) with its suspects' first-seen times."""

    jobs: JobStore
    settings: ServiceSettings
    fence: Callable[[], Fence | None] = lambda: None
    suspects: dict[tuple[str, str], float] = field(default_factory=dict)

    def scan(self, *, grace_s: float | None = None) -> list[str]:
        """One scan; returns the ids of the jobs it finished, requeued or failed."""
        grace_s = self.settings.recovery_grace_s if grace_s is None else grace_s
        now = time.time()
        moved: list[str] = []
        seen: set[tuple[str, str]] = set()
        for job in dispatched_jobs(self.jobs.database, self.settings.stage_lock_ttl_s):
            if job.running:
                continue  # a worker beats its row
            if set(job.stages_done) >= set(STAGES):
                if self._finish(job):
                    moved.append(job.id)
                continue
            if (
                not job.claimed
                and job.idle_s < self.settings.message_wait_s
                and self.jobs.live_phase(job.tenant, job.id) == "waiting"
            ):
                continue  # its next message waits for a worker
            pair = (job.tenant, job.id)
            seen.add(pair)
            first_seen = self.suspects.setdefault(pair, now)
            if first_seen == now and grace_s > 0 or now - first_seen < grace_s:
                continue
            try:
                if self._requeue_or_fail(job):
                    moved.append(job.id)
            except LeaseLost as exc:  # another replica leads now: its own scan takes over
                log.warning("recovery scan stopped: %s", exc)
                break
            seen.discard(pair)
        self.suspects = {p: t for p, t in self.suspects.items() if p in seen}
        return moved

    def _finish(self, job: DispatchedJob) -> bool:
        """All stages done and only the end unwritten: succeeded, from the row (module docstring)."""
        record = self.jobs.load(job.tenant, job.id)
        if record is None or record.state.terminal:
            return False
        ended = lifecycle.finish(self.jobs, record, JobState.succeeded)
        log.warning("finished job %s/%s, whose stages were all done (its end had not been written): %s",
                    job.tenant, job.id, ended.state.value)  # fmt: skip
        return True

    def _requeue_or_fail(self, job: DispatchedJob) -> bool:
        if job.recoveries >= self.settings.max_recoveries:
            record = self.jobs.load(job.tenant, job.id)
            if record is None or record.state.terminal:
                return False
            reason = (f"lost its worker {job.recoveries + 1} times (each stage is re-run from its "
                      f"last finished stage; the limit is BFIELDS_MAX_RECOVERIES={self.settings.max_recoveries})")  # fmt: skip
            lifecycle.finish(self.jobs, record, JobState.failed, reason)
            log.warning("failed job %s/%s: %s", job.tenant, job.id, reason)
            return True
        if self.jobs.queue.requeue(job.tenant, job.id, self.fence(), recovered=True):
            log.warning("requeued orphaned job %s/%s (no worker's heartbeat on its row, no message waiting)",
                        job.tenant, job.id)  # fmt: skip
            return True
        return False
