"""The jobs domain's two ports: the records (rows, in a unit of work) and the live state (progress
and cancel flags), each a Protocol with its production implementation beside it.

Why ports: the rules of a job's life (`model.settle`, a job's end writing its outbox and usage rows
once, admission, idempotency keys) belong to the domain, not to PostgreSQL or Redis. `JobStore`
is given a `JobRecords` and a `LiveJobs`; in production they are `PgJobRecords` (the repositories
of `records/` over one Engine, `records.begin` / `records.connect` as the unit of work) and
`RedisLiveJobs` (the keys of `live.redis_keys`), and the domain tests give it the in-memory fakes
of `tests/services/jobs/fakes.py`, so every rule runs in the inner loop without a server.

A `JobTx` is one transaction (`write`) or one read-only connection (`read`): rows the domain reads
are mappings with the `jobs` / `batches` columns; `load_job(..., lock=True)` holds the row until
the transaction ends (a no-op where nothing runs concurrently, as in the fakes).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, contextmanager
from datetime import datetime
from typing import Any, Protocol

import redis
from sqlalchemy import Connection, Engine

from bayesian_fields_service import records
from bayesian_fields_service.live import redis_keys
from bayesian_fields_service.live.redis_text import text
from bayesian_fields_service.records import answers, batches, keys, outbox, queue, usage
from bayesian_fields_service.records import jobs as job_rows
from bayesian_fields_service.scenes.postgres import lock_ready

Row = Mapping[Any, Any]  # a `jobs` / `batches` row by column name (SQLAlchemy's RowMapping)
#: A usage ledger end row: (entry id, tenant, job id, outcome, bytes stored, when).
EndRow = tuple[str, str, str, str, int, datetime]

#: Seconds a finished job's live Redis hash is kept.
FINISHED_HASH_TTL_S = 24 * 3600
#: Seconds a cancel flag is kept (a week: a running job sees it at its next frame).
CANCEL_FLAG_TTL_S = FINISHED_HASH_TTL_S * 7


class JobTx(Protocol):
    """The statements the jobs domain issues, in one transaction (or one read)."""

    # jobs
    def load_job(self, tenant: str, job_id: str, *, lock: bool = False) -> Row | None: ...
    def load_jobs(self, tenant: str, job_ids: Sequence[str]) -> list[Row]: ...
    def insert_job(self, row: dict[str, Any]) -> None: ...
    def write_job(self, row: dict[str, Any]) -> None: ...
    def insert_jobs(self, rows: list[dict[str, Any]]) -> None: ...
    def page_jobs(self, tenant: str, *, states: Sequence[str] | None, scene_id: str | None,
                  batch_id: str | None, before: str | None, limit: int) -> list[Row]: ...  # fmt: skip
    def count_active(self, tenant: str | None) -> int: ...
    def active_pairs(self) -> list[tuple[str, str]]: ...
    def admission_count(self, tenant: str) -> int: ...
    def dispatched_ids(self, tenant: str) -> list[str]: ...
    def lock_ready_scenes(self, tenant: str, scene_ids: Sequence[str]) -> None: ...
    # idempotency keys
    def lookup_key(self, tenant: str, endpoint: str, key: str) -> tuple[str, str] | None: ...
    def lookup_keys(self, tenant: str, endpoint: str, wanted: list[str]) -> dict[str, tuple[str, str]]: ...
    def remember_keys(self, rows: list[dict[str, str]], *, replace: bool = False) -> None: ...
    def forget_key(self, tenant: str, endpoint: str, key: str, target_id: str) -> None: ...
    # batches
    def insert_batch(self, **row: Any) -> None: ...
    def insert_links(self, batch_id: str, job_ids: Sequence[str]) -> None: ...
    def load_batch(self, tenant: str, batch_id: str) -> Row | None: ...
    def batch_job_rows(self, batch_id: str, *, start: int = 0, limit: int | None = None,
                       states: Sequence[str] | None = None,
                       job_ids: Sequence[str] | None = None) -> list[tuple[int, Row]]: ...  # fmt: skip
    def cancel_batch_jobs(self, tenant: str, batch_id: str, columns: Sequence[str]) -> list[Row]: ...
    def replace_batch_jobs(self, batch_id: str, new_of: dict[str, str]) -> None: ...
    def mark_batches_finished(self, job_ids: Sequence[str]) -> list[Row]: ...
    # what a job's end writes
    def enqueue_event(self, tenant: str, url: str, event: dict[str, Any]) -> bool: ...
    def insert_usage_ends(self, ends: Sequence[EndRow]) -> None: ...
    def replace_answers(self, job_id: str, rows: Sequence[dict[str, Any]]) -> None: ...


class JobRecords(Protocol):
    """The records port: a unit of work (`write`, committed at the end of the block, rolled back
    on an exception) and a read (`read`)."""

    def write(self) -> AbstractContextManager[JobTx]: ...
    def read(self) -> AbstractContextManager[JobTx]: ...


class LiveJobs(Protocol):
    """The live port: progress a job shows while it runs and the cancel flags its worker polls.
    Losing it loses nothing but progress (the rows are the truth)."""

    def touch(self, tenant: str, job_id: str, state: str, stage: str, progress: float, *,
              terminal: bool) -> None: ...  # fmt: skip
    def set_progress(self, tenant: str, job_id: str, stage: str, progress: float) -> None: ...
    def phase(self, tenant: str, job_id: str) -> str | None: ...
    def has_entry(self, tenant: str, job_id: str) -> bool: ...
    def overlays(self, pairs: Sequence[tuple[str, str]]) -> list[dict[bytes, bytes]]: ...
    def flag_cancelled(self, pairs: Iterable[tuple[str, str]]) -> None: ...
    def forget(self, pairs: Sequence[tuple[str, str]]) -> None: ...
    def is_cancel_flagged(self, tenant: str, job_id: str) -> bool: ...


class PgJobTx:
    """`JobTx` over one SQLAlchemy connection: each method one repository function of `records/`."""

    def __init__(self, conn: Connection) -> None:
        self.conn = conn

    def load_job(self, tenant: str, job_id: str, *, lock: bool = False) -> Row | None:
        return job_rows.load(self.conn, tenant, job_id, lock=lock)

    def load_jobs(self, tenant: str, job_ids: Sequence[str]) -> list[Row]:
        return list(job_rows.load_many(self.conn, tenant, job_ids))

    def insert_job(self, row: dict[str, Any]) -> None:
        job_rows.insert_row(self.conn, row)

    def write_job(self, row: dict[str, Any]) -> None:
        job_rows.write_row(self.conn, row)

    def insert_jobs(self, rows: list[dict[str, Any]]) -> None:
        job_rows.insert_many(self.conn, rows)

    def page_jobs(self, tenant: str, *, states: Sequence[str] | None, scene_id: str | None,
                  batch_id: str | None, before: str | None, limit: int) -> list[Row]:  # fmt: skip
        return list(job_rows.page(self.conn, tenant, states=states, scene_id=scene_id, batch_id=batch_id,
                                  before=before, limit=limit))  # fmt: skip

    def count_active(self, tenant: str | None) -> int:
        return job_rows.count_active(self.conn, tenant)

    def active_pairs(self) -> list[tuple[str, str]]:
        return job_rows.active_pairs(self.conn)

    def admission_count(self, tenant: str) -> int:
        return queue.admission_count(self.conn, tenant)

    def dispatched_ids(self, tenant: str) -> list[str]:
        return queue.dispatched_ids(self.conn, tenant)

    def lock_ready_scenes(self, tenant: str, scene_ids: Sequence[str]) -> None:
        lock_ready(self.conn, tenant, scene_ids)

    def lookup_key(self, tenant: str, endpoint: str, key: str) -> tuple[str, str] | None:
        return keys.lookup(self.conn, tenant, endpoint, key)

    def lookup_keys(self, tenant: str, endpoint: str, wanted: list[str]) -> dict[str, tuple[str, str]]:
        return keys.lookup_many(self.conn, tenant, endpoint, wanted)

    def remember_keys(self, rows: list[dict[str, str]], *, replace: bool = False) -> None:
        keys.remember(self.conn, rows, replace=replace)

    def forget_key(self, tenant: str, endpoint: str, key: str, target_id: str) -> None:
        keys.forget(self.conn, tenant, endpoint, key, target_id)

    def insert_batch(self, **row: Any) -> None:
        batches.insert_row(self.conn, **row)

    def insert_links(self, batch_id: str, job_ids: Sequence[str]) -> None:
        batches.insert_links(self.conn, batch_id, job_ids)

    def load_batch(self, tenant: str, batch_id: str) -> Row | None:
        return batches.load(self.conn, tenant, batch_id)

    def batch_job_rows(self, batch_id: str, *, start: int = 0, limit: int | None = None,
                       states: Sequence[str] | None = None,
                       job_ids: Sequence[str] | None = None) -> list[tuple[int, Row]]:  # fmt: skip
        return list(
            batches.job_rows(self.conn, batch_id, start=start, limit=limit, states=states, job_ids=job_ids)
        )

    def cancel_batch_jobs(self, tenant: str, batch_id: str, columns: Sequence[str]) -> list[Row]:
        return list(batches.cancel_jobs(self.conn, tenant, batch_id, columns=columns))

    def replace_batch_jobs(self, batch_id: str, new_of: dict[str, str]) -> None:
        batches.replace_jobs(self.conn, batch_id, new_of)

    def mark_batches_finished(self, job_ids: Sequence[str]) -> list[Row]:
        return list(batches.mark_finished(self.conn, job_ids))

    def enqueue_event(self, tenant: str, url: str, event: dict[str, Any]) -> bool:
        return outbox.enqueue(self.conn, tenant, url, event["event_id"], event)

    def insert_usage_ends(self, ends: Sequence[EndRow]) -> None:
        usage.insert_ends(self.conn, ends)

    def replace_answers(self, job_id: str, rows: Sequence[dict[str, Any]]) -> None:
        answers.replace_job(self.conn, job_id, rows)


class PgJobRecords:
    """`JobRecords` on the records database (the production path)."""

    def __init__(self, engine: Engine) -> None:
        self.engine = engine

    @contextmanager
    def write(self) -> Iterator[JobTx]:
        with records.begin(self.engine) as conn:
            yield PgJobTx(conn)

    @contextmanager
    def read(self) -> Iterator[JobTx]:
        with records.connect(self.engine) as conn:
            yield PgJobTx(conn)


class RedisLiveJobs:
    """`LiveJobs` in Redis: one hash per job (`live.redis_keys.live_job`) and one cancel flag
    (`live.redis_keys.cancel_flag`); the production path."""

    def __init__(self, client: redis.Redis) -> None:
        self.client = client

    def touch(self, tenant: str, job_id: str, state: str, stage: str, progress: float, *,
              terminal: bool) -> None:  # fmt: skip
        """The job's hash, phase 'waiting' (a message is queued for its next stage); kept a day
        once the job ended, for good while it runs."""
        key = redis_keys.live_job(tenant, job_id)
        pipe = self.client.pipeline()
        pipe.hset(key, mapping={"state": state, "stage": stage, "progress": progress, "phase": "waiting",
                                "updated": time.time()})  # fmt: skip
        if terminal:
            pipe.expire(key, FINISHED_HASH_TTL_S)
        else:
            pipe.persist(key)
        pipe.execute()

    def set_progress(self, tenant: str, job_id: str, stage: str, progress: float) -> None:
        """A running stage's progress, phase 'active' (its worker holds the stage lock)."""
        self.client.hset(redis_keys.live_job(tenant, job_id), mapping={
            "state": "running", "stage": stage, "progress": progress, "phase": "active", "updated": time.time(),
        })  # fmt: skip

    def phase(self, tenant: str, job_id: str) -> str | None:
        found = self.client.hget(redis_keys.live_job(tenant, job_id), "phase")
        return text(found) if found is not None else None

    def has_entry(self, tenant: str, job_id: str) -> bool:
        return bool(self.client.exists(redis_keys.live_job(tenant, job_id)))

    def overlays(self, pairs: Sequence[tuple[str, str]]) -> list[dict[bytes, bytes]]:
        """The hashes of `pairs` (tenant, job id) in one round trip (an empty dict: none)."""
        pipe = self.client.pipeline()
        for tenant, job_id in pairs:
            pipe.hgetall(redis_keys.live_job(tenant, job_id))
        return list(pipe.execute())

    def flag_cancelled(self, pairs: Iterable[tuple[str, str]]) -> None:
        pipe = self.client.pipeline(transaction=False)
        for tenant, job_id in pairs:
            pipe.set(redis_keys.cancel_flag(tenant, job_id), b"1", ex=CANCEL_FLAG_TTL_S)
        pipe.execute()

    def forget(self, pairs: Sequence[tuple[str, str]]) -> None:
        if pairs:
            self.client.delete(*[redis_keys.live_job(t, j) for t, j in pairs])

    def is_cancel_flagged(self, tenant: str, job_id: str) -> bool:
        return bool(self.client.exists(redis_keys.cancel_flag(tenant, job_id)))
