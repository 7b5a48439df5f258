"""Release waiting jobs to the worker queues, fairly between tenants (`jobs.queue`).

Run by the control process's leader only. A round tops the GPU queue up to
`dispatch_queue_depth` messages: it reads the backlog once (two grouped index scans), then per
message chooses a tenant by stride scheduling, stamps that tenant's next waiting job dispatched
(one ``UPDATE ... FOR UPDATE SKIP LOCKED`` statement) and sends the job's remaining stages as one
Celery chain. Why the queue stays short: the Celery queues are FIFO, so what is in them is no
longer fair; a new tenant's first job waits behind at most `dispatch_queue_depth` messages.

A crash after the stamp and before the send leaves a dispatched job with no message: recovery
finds it (no stage lock, no message) and clears the stamp, which puts it back at the front of its
tenant's queue. A send whose broker is down gives the stamp back at once. A chain sent twice (a
crash after the send, then recovery) is harmless: stages are locked and skip finished work.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import redis
from celery import Celery

from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.jobs import lifecycle
from bayesian_fields_service.jobs.model import JobRecord, JobState
from bayesian_fields_service.jobs.queue import StrideClock, TenantBacklog, choose
from bayesian_fields_service.jobs.store import JobStore
from bayesian_fields_service.live.broker import enqueue_stages, queue_length
from bayesian_fields_service.live.metrics import observe_queue_wait
from bayesian_fields_service.observability import tracing
from bayesian_fields_service.observability.logs import log_context
from bayesian_fields_service.records.ids import id_age_s
from bayesian_fields_service.records.leases import Fence, LeaseLost

log = logging.getLogger(__name__)


class Dispatcher:
    """The fair-share dispatcher (module docstring); `round` is called by the leader's loop."""

    def __init__(
        self,
        app: Celery,
        jobs: JobStore,
        settings: ServiceSettings,
        client: redis.Redis,
        fence: Callable[[], Fence | None] = lambda: None,
    ) -> None:
        self.app = app
        self.fence = fence
        self.jobs = jobs
        self.settings = settings
        self.client = client
        self.clock = StrideClock()

    def round(self) -> int:
        """Dispatch while the GPU queue has room and some tenant may go; returns jobs sent. Each
        stamp carries the leader's fence, so a round a frozen leader resumes after losing its
        lease stamps nothing (`records.leases`)."""
        s = self.settings
        fence = self.fence()
        room = s.dispatch_queue_depth - queue_length(self.client, s.gpu_queue)
        if room <= 0:
            return 0
        backlog = self.jobs.queue.backlog()
        self.clock.observe(backlog)
        sent = 0
        while room > 0:
            pick = choose(backlog, s.max_active_jobs_per_tenant, set())
            if pick is None:
                return sent
            try:
                record = self.jobs.dispatch_next(pick.tenant, fence)
            except LeaseLost as exc:
                log.warning("dispatch round stopped: %s", exc)
                return sent
            if record is None:  # what it had was cancelled (or is being changed) meanwhile
                pick.interactive = pick.bulk = 0
                continue
            self._count(pick, record)
            self.clock.advance(pick, s.weight(pick.tenant))
            self._send(record)
            sent += 1
            room -= 1
        return sent

    @staticmethod
    def _count(pick: TenantBacklog, record: JobRecord) -> None:
        if record.priority == "interactive":
            pick.interactive = max(0, pick.interactive - 1)
        else:
            pick.bulk = max(0, pick.bulk - 1)
        pick.dispatched += 1

    def _send(self, record: JobRecord) -> None:
        """`_send_job` in the job's trace (its row's traceparent: the submission's span) and with
        its ids on every log line."""
        attributes = {"bfields.job_id": record.id, "bfields.tenant": record.tenant,
                      "bfields.stages": ",".join(record.remaining_stages())}  # fmt: skip
        ids = log_context(job_id=record.id, tenant=record.tenant)
        with ids, tracing.job_span("dispatch", attributes, record.traceparent):
            self._send_job(record)

    def _send_job(self, record: JobRecord) -> None:
        """The job's remaining stages as one chain; the stamp is given back if the send fails. A
        job with no stage left (its end was not written) is finished here instead: a chain of no
        stage would leave it dispatched for ever."""
        if not record.remaining_stages():
            ended = lifecycle.finish(self.jobs, record, JobState.succeeded)
            log.warning("finished job %s/%s on dispatch: every stage was done (%s)", record.tenant, record.id,
                        ended.state.value)  # fmt: skip
            return
        try:
            enqueue_stages(self.app, record.tenant, record.id, record.remaining_stages(),
                           gpu_queue=self.settings.gpu_queue, cpu_queue=self.settings.cpu_queue)  # fmt: skip
        except BaseException:
            self.jobs.queue.undo_take(record.tenant, record.id)
            raise
        try:
            if not record.stages_done and record.stage_runs == 0:
                observe_queue_wait(self.client, record.tenant, id_age_s(record.id))
            self.jobs.touch_live(record)  # phase 'waiting': a message is queued for it
        except redis.RedisError as exc:  # display only: the message is out
            log.warning("dispatched %s/%s without its live state (%s)", record.tenant, record.id, exc)
