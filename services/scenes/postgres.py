"""The scene records port (`ports.SceneRecords`) on PostgreSQL, over `records.scenes`.

Why the row locks matter here: a scene's fate is decided by three requests that may race
(`complete` publishing the upload, `delete`, a job submission on the scene); the scene's own row
lock orders them (`store` says how). ``load(lock=True)`` is ``FOR UPDATE``, ``share_lock`` is
``FOR SHARE`` in id order, and the completion claim is an advisory session lock (it spans minutes
of copying, which must not hold a transaction open; a process that dies gives it up with its
session).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from datetime import UTC
from typing import Any

from sqlalchemy import Connection, Engine

from bayesian_fields_service import records
from bayesian_fields_service.records import answers as answer_records
from bayesian_fields_service.records import jobs as job_rows
from bayesian_fields_service.records import scenes as scene_rows
from bayesian_fields_service.records.locks import LockBusy, session_locks
from bayesian_fields_service.scenes.model import DELETING, DeletingScene, SceneRecord, SceneRow
from bayesian_fields_service.scenes.refusals import CompletionBusy
from bayesian_fields_service.scenes.store import SceneStore, ready_scenes

_FIELDS = ("id", "tenant", "name", "state", "files", "bytes", "summary", "pending_uploads", "created_at",
           "updated_at")  # fmt: skip


def _record_of(row: Any) -> SceneRecord:
    """A record from a row, its times in UTC whatever the database session's time zone (an
    answer reads the same as the one the upload gave)."""
    data = {name: row[name] for name in _FIELDS}
    data["created_at"], data["updated_at"] = (
        data["created_at"].astimezone(UTC),
        data["updated_at"].astimezone(UTC),
    )
    return SceneRecord.model_validate(data)


def _scene_of(row: Any) -> SceneRow:
    if row["state"] == DELETING:
        return DeletingScene(row["tenant"], row["id"], list(row["pending_uploads"]))
    return _record_of(row)


def _row_of(record: SceneRecord, state: str | None = None) -> dict[str, Any]:
    row = record.model_dump(mode="json")
    row["created_at"], row["updated_at"] = record.created_at, record.updated_at
    row["state"] = state or record.state.value
    return {name: row[name] for name in _FIELDS}


class PostgresSceneRows:
    """`ports.SceneRows` on one connection (in the caller's transaction, if any)."""

    def __init__(self, conn: Connection) -> None:
        self.conn = conn

    def insert(self, record: SceneRecord) -> None:
        scene_rows.insert_row(self.conn, _row_of(record))

    def adopt(self, record: SceneRecord, *, deleting: bool) -> bool:
        return scene_rows.insert_if_absent(self.conn, _row_of(record, DELETING if deleting else None))

    def load(self, tenant: str, scene_id: str, *, lock: bool = False) -> SceneRow | None:
        row = scene_rows.load(self.conn, tenant, scene_id, lock=lock)
        return None if row is None else _scene_of(row)

    def share_lock(self, tenant: str, scene_ids: Sequence[str]) -> dict[str, SceneRow]:
        return {i: _scene_of(r) for i, r in scene_rows.share_lock(self.conn, tenant, scene_ids).items()}

    def page(self, tenant: str, limit: int, before: str | None) -> list[SceneRecord]:
        return [_record_of(r) for r in scene_rows.page(self.conn, tenant, limit, before)]

    def set_ready(
        self, tenant: str, scene_id: str, *, files: int, size: int, summary: dict[str, Any]
    ) -> SceneRecord:
        return _record_of(
            scene_rows.set_ready(self.conn, tenant, scene_id, files=files, size=size, summary=summary)
        )

    def set_deleting(self, tenant: str, scene_id: str) -> None:
        scene_rows.set_deleting(self.conn, tenant, scene_id)

    def purge(self, tenant: str, scene_id: str) -> None:
        scene_rows.purge(self.conn, tenant, scene_id)

    def deleting(self) -> list[DeletingScene]:
        return [DeletingScene(t, i, pending) for t, i, pending in scene_rows.deleting(self.conn)]

    def pending_uploads(self, tenant: str, scene_ids: Sequence[str]) -> dict[str, list[dict[str, Any]]]:
        return scene_rows.pending_uploads(self.conn, tenant, scene_ids)

    def active_job(self, tenant: str, scene_id: str) -> tuple[str, str] | None:
        active = job_rows.active_on_scene(self.conn, tenant, scene_id)
        return None if active is None else (active["id"], active["state"])

    def drop_answers(self, tenant: str, scene_id: str) -> None:
        answer_records.delete_scene(self.conn, tenant, scene_id)


class PostgresSceneRecords:
    """`ports.SceneRecords` on the records engine."""

    def __init__(self, database: Engine) -> None:
        self.database = database

    @contextlib.contextmanager
    def transaction(self) -> Iterator[PostgresSceneRows]:
        with records.begin(self.database) as conn:
            yield PostgresSceneRows(conn)

    @contextlib.contextmanager
    def read(self) -> Iterator[PostgresSceneRows]:
        with records.connect(self.database) as conn:
            yield PostgresSceneRows(conn)

    @contextlib.contextmanager
    def completion_claim(self, tenant: str, scene_id: str) -> Iterator[None]:
        try:
            with session_locks(self.database, [("scene-completion", tenant, scene_id)], wait_s=None):
                yield
        except LockBusy:
            raise CompletionBusy(scene_id) from None


def scene_store(database: Engine) -> SceneStore:
    """The scene rows' rules on the process's records engine."""
    return SceneStore(PostgresSceneRecords(database))


def lock_ready(conn: Connection, tenant: str, scene_ids: Sequence[str]) -> dict[str, SceneRecord]:
    """`store.ready_scenes` in the caller's transaction (a job submission's): ``FOR SHARE`` on
    the scenes' rows until its jobs are committed, so a delete waits for them and sees the jobs."""
    return ready_scenes(PostgresSceneRows(conn), tenant, scene_ids)
