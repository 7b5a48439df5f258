"""The stage tasks: one Celery task per pipeline stage, each idempotent and resumable.

A task (tenant, job id) loads the job's record (its row), skips a stage already in its
`stages_done`, otherwise claims the job on its row (`StageClaim`: the worker's name and a
heartbeat, beaten every quarter of the lease while the stage runs) and runs `run_stage`,
reporting progress to Redis (display only) and the outcome to the row. Failure handling:
- `InputError` (bad scene, bad parameter): the job fails with the message; no retry;
- `CancelledError` (the cancel flag, checked between frames): the job is cancelled;
- connection / storage errors, or the records database unreachable at the stage's start: retried
  with exponential backoff, at most ``job_max_retries``; the stage's and the job's end are retried
  until they land (`jobs.durable_writes`);
- a killed worker: its claim lapses after the lease and the control process's recovery, which
  reads the row, puts the job back in the queue (`control.recovery`); the stage re-runs from its
  last finished marker;
- a killed pool child: Celery requeues its message at once (reject_on_worker_lost); the dead
  child's claim is taken over as soon as its owner process is known dead (same host), else the
  delivery waits, with a countdown of the claim's remaining lease and no limit on such waits,
  until it lapses. Waiting for a claim never uses the transient-error retry budget.
Models are built once per worker process, keyed by profile. The scene is read from one local copy
per scene and content version, shared by the host's pool processes (`scene_cache`).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import socket
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import redis
from celery import Task
from celery.exceptions import SoftTimeLimitExceeded
from celery.signals import worker_init, worker_process_init
from celery.utils.log import get_logger
from sqlalchemy.exc import InterfaceError, OperationalError

from bayesian_fields_core.errors import CancelledError, InputError, ModelError
from bayesian_fields_core.job.factories import store_job
from bayesian_fields_core.job.pipeline import discard_result, run_stage
from bayesian_fields_core.job.scene_source import SceneOrigin
from bayesian_fields_core.job.span_attributes import stage_attributes
from bayesian_fields_core.job.stage_table import STAGE_TABLE, StageSpec
from bayesian_fields_core.job.store import Store
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import Models, load_models
from bayesian_fields_service import hooks
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.jobs import lifecycle
from bayesian_fields_service.jobs.durable_writes import until_landed
from bayesian_fields_service.jobs.model import JobRecord, JobState
from bayesian_fields_service.jobs.store import JobStore
from bayesian_fields_service.live.metrics import observe_stage
from bayesian_fields_service.live.single_flight import RedisFlight
from bayesian_fields_service.observability import tracing
from bayesian_fields_service.observability.logs import log_context
from bayesian_fields_service.records import job_heartbeats
from bayesian_fields_service.records.database import open_records
from bayesian_fields_service.storage.stores import build_store, tenant_store
from bayesian_fields_service.worker import stage_metrics
from bayesian_fields_service.worker.accounting import StageMeter, account_stage
from bayesian_fields_service.worker.celery_app import app
from bayesian_fields_service.worker.scene_cache import SceneCache

log = get_logger(__name__)  # a child of the 'celery' logger: lands in the worker log

#: Errors worth retrying: the network or a server, never the input.
TRANSIENT: tuple[type[Exception], ...] = (
    redis.ConnectionError,
    redis.TimeoutError,
    ConnectionError,
    TimeoutError,
    # the records database unreachable (a stage's start, before any work): retried like Redis
    OperationalError,
    InterfaceError,
)
try:  # storage errors only exist when boto3 is installed
    from bayesian_fields_service.storage.s3_store import StorageError

    TRANSIENT = (*TRANSIENT, StorageError)
except ImportError:  # pragma: no cover - local-store deployments
    pass

PROGRESS_INTERVAL_S = 0.5


class _Runtime:
    """Per-process singletons: settings, store, Redis, job store, models by profile."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._models: dict[str, Models] = {}
        self.settings: ServiceSettings = app.conf.bfields_settings
        self.store = build_store(self.settings)
        self.redis = redis.Redis.from_url(
            self.settings.redis_url, socket_timeout=10, socket_connect_timeout=5
        )
        database = open_records(self.settings.database_url, migrate_first=self.settings.migrate_on_start)
        self.jobs = JobStore(self.store, self.redis, database)
        self.scene_cache = scene_cache(self.settings)

    def models(self, profile: str) -> Models:
        with self._lock:
            if profile not in self._models:
                source: Any = self.settings.model_profile if profile == "default" else profile
                device = _worker_device(self.settings.worker_device)
                log.info("loading model profile %s on %s", profile, device)
                models = load_models(source, device=device)
                models.encoder_wrapper = lambda encoder: hooks.wrap("encoder", encoder)
                self._models[profile] = models
            return self._models[profile]


def _worker_device(setting: str) -> str:
    """The torch device of this worker: 'cpu', 'cuda' (refused loudly when absent, so a GPU pool
    scheduled on a node without a working GPU fails instead of crawling on the CPU), or 'auto'."""
    if setting == "cpu":
        return "cpu"
    import torch

    if torch.cuda.is_available():
        return "cuda"
    if setting == "cuda":
        raise RuntimeError("BFIELDS_WORKER_DEVICE=cuda but torch sees no CUDA device")
    log.warning("BFIELDS_WORKER_DEVICE=auto: no CUDA device, running on the CPU")
    return "cpu"


def scene_cache(settings: ServiceSettings) -> SceneCache:
    """The host's scene copies (BFIELDS_WORKER_SCENE_CACHE_DIR, bounded by ..._MAX_BYTES)."""
    root = settings.worker_scene_cache_dir or Path(tempfile.gettempdir()) / "bfields-scene-cache"
    return SceneCache(root, settings.worker_scene_cache_max_bytes)


_runtime: _Runtime | None = None


def runtime() -> _Runtime:
    global _runtime
    if _runtime is None:
        _runtime = _Runtime()
    return _runtime


@worker_process_init.connect
def _reset_runtime(**_: Any) -> None:
    """Forked pool processes must not share the parent's sockets: rebuild lazily."""
    global _runtime
    _runtime = None


@worker_init.connect
def _clean_scene_cache(**_: Any) -> None:
    """At start (main process, before the pool forks): drop partial scene copies a killed worker
    left, enforce the disk bound, and delete the per-stage copies older versions left in
    <temp dir>/bfields-scenes."""
    settings: ServiceSettings = app.conf.bfields_settings
    try:
        scene_cache(settings).clean_start()
        shutil.rmtree(Path(tempfile.gettempdir()) / "bfields-scenes", ignore_errors=True)
    except OSError as exc:  # a read-only or full disk must not keep the worker from starting
        log.warning("scene cache clean-up failed: %s", exc)


def _process_start(pid: int) -> str | None:
    """The start time of process `pid` (clock ticks since boot, from /proc), so a recycled pid is
    not mistaken for the original; None when the process does not exist or is a zombie."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return None
    except OSError:  # no /proc (not Linux): existence only
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None
        except PermissionError:
            pass
        return "?"
    fields = stat.rsplit(")", 1)[1].split()
    return None if fields[0] in ("Z", "X") else fields[19]


_HOST = socket.gethostname()


def worker_name() -> str:
    """This process's name on a job's row: ``host:pid:process start:random`` (unique per claim,
    so it fences its own beats; host, pid and start let a delivery on the same host see that a
    holder is dead)."""
    pid = os.getpid()
    return f"{_HOST}:{pid}:{_process_start(pid)}:{secrets.token_hex(8)}"


def _dead_on_this_host(holder: str | None) -> bool:
    """`holder` ran on this host and that process is gone (a SIGKILLed pool child)."""
    if not holder:
        return False
    host, _, rest = holder.partition(":")
    pid, _, rest = rest.partition(":")
    started = rest.partition(":")[0]
    return host == _HOST and pid.isdigit() and _process_start(int(pid)) != started


class StageClaim:
    """The job claimed on its row for one stage execution, with a heartbeat while it runs
    (`records.job_heartbeats`), so a duplicate delivery never runs a stage of the job at the same
    time and recovery knows the job is alive without asking Redis. A crashed holder's claim
    lapses `stage_lock_ttl_s` after its last beat; one on this host whose process is gone is taken
    over at once. Each beat reads the job's cancel flag back (`cancel_requested`): a cancel
    reaches the stage even with Redis away. A beat that fails (the database away) is tried again
    at the next; one that finds the claim gone stops the beating, not the stage."""

    def __init__(self, rt: _Runtime, tenant: str, job_id: str) -> None:
        self.rt = rt
        self.tenant, self.job_id = tenant, job_id
        self.worker = worker_name()
        self.lease_s = float(rt.settings.stage_lock_ttl_s)
        self.cancel_requested = threading.Event()
        self._remaining_s = 0.0
        self.ended = False  # the job was no longer active when it was claimed
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def acquire(self) -> bool:
        """Claim the job; on success the heartbeat starts."""
        db = self.rt.jobs.database
        got = job_heartbeats.claim(db, self.tenant, self.job_id, self.worker, self.lease_s)
        if not got.taken and not got.ended and _dead_on_this_host(got.holder):
            got = job_heartbeats.claim(db, self.tenant, self.job_id, self.worker, self.lease_s,
                                       dead_owner=got.holder)  # fmt: skip
            if got.taken:
                log.warning("job %s/%s: its holder %s is dead; taken over", self.tenant, self.job_id,
                            self.holder_pid(got.holder))  # fmt: skip
        if not got.taken:
            self._remaining_s = got.remaining_s
            self.ended = got.ended
            return False
        self._thread = threading.Thread(target=self._run, name="bf-stage-heartbeat", daemon=True)
        self._thread.start()
        return True

    @staticmethod
    def holder_pid(holder: str | None) -> str:
        return (holder or "").split(":")[1] if holder and holder.count(":") >= 1 else "?"

    def wait_s(self) -> float:
        """Seconds until the current holder's claim lapses unless it beats (at least 1)."""
        return max(1.0, self._remaining_s + 0.5)

    def _run(self) -> None:
        while not self._stop.wait(self.lease_s / 4):
            try:
                found = job_heartbeats.beat(self.rt.jobs.database, self.tenant, self.job_id, self.worker)
            except Exception as exc:  # the database away for a moment: the next beat tries again
                log.warning(
                    "heartbeat of %s/%s not written (%s)", self.tenant, self.job_id, type(exc).__name__
                )
                continue
            if found.cancel_requested:
                self.cancel_requested.set()
            if not found.held:
                log.warning(
                    "job %s/%s ended or was taken over; its heartbeat stops", self.tenant, self.job_id
                )
                return

    def release(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        try:
            job_heartbeats.stage_ended(self.rt.jobs.database, self.tenant, self.job_id, self.worker)
        except Exception as exc:  # the claim lapses by itself after the lease
            log.warning("claim of %s/%s not given up (%s)", self.tenant, self.job_id, type(exc).__name__)


def _finish(rt: _Runtime, record: JobRecord, state: JobState, error: str | None = None) -> JobRecord:
    """End the job, retrying while the records database is unreachable (`durable_writes`)."""
    return until_landed(
        lambda: lifecycle.finish(rt.jobs, record, state, error),
        budget_s=rt.settings.record_write_budget_s,
        what=f"the end of job {record.tenant}/{record.id} ({state.value})",
    )


def _account(rt: _Runtime, record: JobRecord, stage: str, meter: StageMeter) -> JobRecord:
    stage_metrics.observe_resources(rt.redis, stage, meter)
    return account_stage(rt.store, rt.jobs.database, record, stage, meter,
                         write_budget_s=rt.settings.record_write_budget_s)  # fmt: skip


def execute_stage(task: Task, stage: str, tenant: str, job_id: str, lock_waits: int = 0) -> str:
    """The body of every stage task; returns what happened ('ran', 'skipped', 'cancelled', ...).
    `lock_waits`: how many of this delivery's retries were waits for another delivery's claim.

    The job is claimed on its row first thing after the message is read, so a worker that dies
    from then on leaves a claim that lapses (and recovery takes the job back), never a job that
    looks as if its message still waited. Reading the row and claiming it wait out a records
    database outage (`durable_writes`) instead of spending the transient-error retries."""
    rt = runtime()
    budget = rt.settings.record_write_budget_s
    record = until_landed(lambda: rt.jobs.load(tenant, job_id), budget_s=budget, what=f"reading job {job_id}")
    if record is None:
        log.warning("job %s/%s has no record; dropping %s", tenant, job_id, stage)
        return "missing"
    if record.state.terminal:
        return f"already {record.state.value}"
    lock = StageClaim(rt, tenant, job_id)
    if not until_landed(lock.acquire, budget_s=budget, what=f"claiming job {job_id}"):
        if lock.ended:
            return "ended"
        # Another delivery runs a stage of this job (or its holder died on another host): try
        # again when its claim would lapse. Unlimited: a live holder beats its claim, and a dead
        # one's lapses within stage_lock_ttl_s, so this ends.
        countdown = lock.wait_s()
        log.info("stage %s of %s is locked; retry in %.1fs", stage, job_id, countdown)  # claimed on its row
        raise task.retry(countdown=countdown, kwargs={"lock_waits": lock_waits + 1})
    try:
        if lifecycle.should_stop(rt.jobs, record):
            _finish(rt, record, JobState.cancelled, "cancelled by request")
            return "cancelled"
        if stage in record.stages_done:
            # A duplicate message (recovery's enqueue of a job the API had enqueued after all): the
            # stage ran and is recorded; not counted as a stage run, and the chain goes on.
            return "skipped"
        # The message taken and the job claimed, the stage not started: a test kills the worker here.
        hooks.point("stage.before_lock", tenant=tenant, job_id=job_id, stage=stage, scene_id=record.scene_id)
        return _run_locked(rt, record, stage, lock)
    finally:
        lock.release()


@dataclass
class SharedSceneCopy:
    """The job's scene as a `SceneSource`: a copy leased from the host's shared scene cache
    instead of a new download per stage; the lease is held in `leases` until the stage returns."""

    cache: SceneCache
    store: Store
    tenant: str
    scene_id: str
    prefix: str
    leases: contextlib.ExitStack

    def folder(self) -> Path:
        lease = self.cache.lease(self.store, self.tenant, self.scene_id, self.prefix)
        return self.leases.enter_context(lease)

    def origin(self) -> SceneOrigin:
        """The scene's prefix in the tenant's store (what the copy was made from)."""
        return SceneOrigin(prefix=self.prefix)


def _run_locked(rt: _Runtime, record: JobRecord, stage: str, claim: StageClaim) -> str:
    tenant, job_id = record.tenant, record.id
    record = until_landed(
        lambda: lifecycle.start_stage(rt.jobs, record, stage),
        budget_s=rt.settings.record_write_budget_s,
        what=f"the start of stage {stage} of job {tenant}/{job_id}",
    )
    if record.state.terminal:
        return f"already {record.state.value}"
    last = [0.0]

    def progress(name: str, fraction: float) -> None:
        # a plugin can act here (a test holds cluster at 0.8: objects found, result not written)
        hooks.point("stage.progress", tenant=tenant, job_id=job_id, step=name, fraction=fraction)
        now = time.monotonic()
        if now - last[0] >= PROGRESS_INTERVAL_S or fraction >= 1.0:
            last[0] = now
            try:
                rt.jobs.set_progress(record, name, fraction)
            except redis.RedisError:
                log.warning("progress update for %s lost (Redis unavailable)", job_id)

    def should_cancel() -> bool:
        """The row's flag as the last heartbeat read it, or Redis's copy (set at once by the API)."""
        if claim.cancel_requested.is_set():
            return True
        try:
            return rt.jobs.is_cancel_requested(tenant, job_id)
        except redis.RedisError:
            return False

    meter = StageMeter(gpu=False)  # GPU-seconds: set below once the models' device is known
    try:
        store = tenant_store(rt.store, tenant)
        leases = contextlib.ExitStack()
        source = SharedSceneCopy(rt.scene_cache, store, tenant, record.scene_id, record.scene_prefix, leases)
        job = store_job(
            store,
            record.job_prefix,
            record.scene_prefix,
            record.tasks,
            # The worker's own device (BFIELDS_WORKER_DEVICE) wins over a job's: clients cannot
            # know which hardware a pool has.
            PipelineParams.model_validate({**record.parameters, "device": None}),
            rt.models(record.model_profile),
            scene_source=source,
            progress=progress,
            should_cancel=should_cancel,
            flight=RedisFlight(
                rt.redis, tenant, ttl_s=rt.settings.flight_lock_ttl_s,
                wait_timeout_s=rt.settings.flight_wait_timeout_s, poll_s=rt.settings.flight_poll_s,
            ),
        )  # fmt: skip
        meter.gpu = (job.runner.models.device or "").startswith("cuda")
        t0 = time.perf_counter()
        span = tracing.job_span(f"stage {stage}", {"bfields.job_id": job_id, "bfields.tenant": tenant})
        # the scene copy stays in use (not evictable) until the stage ends
        with leases, meter, span as handle:
            report = run_stage(stage, job)
            handle.set_attributes(stage_attributes(stage, report))  # its frame / mask / Gaussian counts
        seconds = time.perf_counter() - t0
    except CancelledError:
        record = _account(rt, record, stage, meter)
        _finish(rt, record, JobState.cancelled, "cancelled by request")
        discard_result(tenant_store(rt.store, tenant), record.job_prefix)  # a stage stopped mid-write
        return "cancelled"
    except (InputError, ModelError) as exc:
        record = _account(rt, record, stage, meter)
        _finish(rt, record, JobState.failed, f"{stage}: {exc}")
        return "failed"
    except TRANSIENT:
        raise  # retried by the task wrapper
    except SoftTimeLimitExceeded:
        record = _account(rt, record, stage, meter)
        _finish(
            rt,
            record,
            JobState.failed,
            f"{stage}: exceeded the time limit of {rt.settings.job_soft_time_limit_s} s",
        )
        return "failed"
    except Exception as exc:  # a bug, not bad input: fail the job visibly instead of leaving it running
        log.exception("stage %s of %s/%s crashed", stage, tenant, job_id)
        record = _account(rt, record, stage, meter)
        _finish(rt, record, JobState.failed, f"{stage}: internal error: {type(exc).__name__}: {exc}")
        return "failed"
    observe_stage(rt.redis, stage, seconds)
    accounted = _account(rt, record, stage, meter)
    record = until_landed(
        lambda: lifecycle.stage_done(rt.jobs, accounted, stage, report, seconds),
        budget_s=rt.settings.record_write_budget_s,
        what=f"the end of stage {stage} of job {tenant}/{job_id}",
    )
    if lifecycle.all_stages_done(record):
        final = _finish(rt, record, JobState.succeeded)
        if final.state == JobState.cancelled:  # a cancel accepted before the success was stored
            discard_result(tenant_store(rt.store, tenant), record.job_prefix)
            return "cancelled"
    return "ran"


def _fail_after_retries(rt: _Runtime, tenant: str, job_id: str, stage: str, exc: BaseException) -> None:
    record = rt.jobs.load(tenant, job_id)
    if record is not None and not record.state.terminal:
        _finish(rt, record, JobState.failed, f"{stage}: gave up after retries: {type(exc).__name__}: {exc}")


def _make_stage_task(spec: StageSpec) -> Task:
    stage = spec.name

    # max_retries=None: Celery sets no limit; the transient-error budget is counted here, apart
    # from the waits for a stage lock (`lock_waits`), which must last until the lock's TTL.
    @app.task(name=spec.task_name, bind=True, acks_late=True, reject_on_worker_lost=True, max_retries=None)
    def stage_task(self: Task, tenant: str, job_id: str, lock_waits: int = 0) -> str:
        with log_context(job_id=job_id, tenant=tenant, stage=stage):
            tracing.annotate({"bfields.job_id": job_id, "bfields.tenant": tenant, "bfields.stage": stage})
            return _stage_task(self, tenant, job_id, lock_waits)

    def _stage_task(self: Task, tenant: str, job_id: str, lock_waits: int) -> str:
        rt = runtime()
        stage_metrics.observe_queue_wait(rt.redis, stage, self.request)
        try:
            outcome = execute_stage(self, stage, tenant, job_id, lock_waits)
            if outcome not in ("ran", "skipped"):
                self.request.chain = None  # the job ended here: do not start the next stage
            return outcome
        except TRANSIENT as exc:
            failures = self.request.retries - lock_waits
            if failures >= rt.settings.job_max_retries:
                _fail_after_retries(rt, tenant, job_id, stage, exc)
                raise
            countdown = min(60, 2 ** (failures + 1))
            log.warning("stage %s of %s: %s; retry in %ss", stage, job_id, exc, countdown)
            raise self.retry(exc=exc, countdown=countdown, kwargs={"lock_waits": lock_waits}) from exc

    return stage_task


STAGE_TASKS: dict[str, Task] = {spec.name: _make_stage_task(spec) for spec in STAGE_TABLE}
"""One Celery task per row of the stage table, registered under `StageSpec.task_name`."""
