"""Scene records: a row of the `scenes` table is the truth about a scene; its files stay in the
bucket under ``tenants/<t>/scenes/<id>/``.

Why rows: a scene's fate is decided by three requests that may race (`complete` publishing the
upload, `delete`, a job submission on the scene). In the bucket that took a record object, index
markers, deletion marks and advisory locks kept in step by hand; as rows, the scene's own row lock
orders them and its state says what happened:

- ``uploading`` (a presigned upload not yet completed) -> ``ready`` (`SceneStore.publish_ready`,
  under ``FOR UPDATE``) -> ``deleting`` (`SceneStore.mark_deleting`, under ``FOR UPDATE``, refused
  while a job on the scene is queued or running) -> no row (`SceneStore.purge`, once the scene's
  objects are gone). A ``deleting`` row is gone for every reader (`get` and `list` skip it), and
  no step turns it back: an acknowledged delete is final by the row's state. What a delete that
  stopped half-way leaves, the orphan sweeper finishes (`deleting_scenes`).
- A job submission calls `lock_ready` in the transaction that inserts its jobs: ``FOR SHARE``
  on the scenes' rows until the jobs are committed. So a delete either waits for the submission
  and then sees its active job (refused), or comes first and the submission sees ``deleting``
  (`SceneGone`).

Ids are time-ordered (``s_`` + ms timestamp + randomness, `common.jobs.new_id`), so newest first
is descending id order, which is also the listing's cursor.
"""

from __future__ import annotations

import builtins
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from enum import StrEnum
from typing import Any

from pydantic import BaseModel, Field
from sqlalchemy import Connection, Engine

from bayesian_fields_service import records
from bayesian_fields_service.records import answers as answer_records
from bayesian_fields_service.records import jobs as job_rows
from bayesian_fields_service.records import scenes as scene_rows

SCENE_EXAMPLE_ID = "s_0192f3a1b2c3aa55bb66cc"
#: The row state of a scene whose delete was acknowledged (never shown by the API: a 404).
DELETING = scene_rows.DELETING


# The states the API shows; a row may also be `DELETING`, which reads as absent. (No docstring:
# it would become the schema's description, which the API's clients already have without one.)
class SceneState(StrEnum):
    uploading = "uploading"
    ready = "ready"


class SceneRecord(BaseModel):
    """A scene as its record stores it: what was uploaded and what validation found."""

    id: str = Field(examples=[SCENE_EXAMPLE_ID])
    tenant: str = Field(examples=["acme"])
    name: str | None = Field(None, examples=["kitchen-2024-05-01"])
    state: SceneState = SceneState.ready
    files: int = Field(0, description="Files stored under the scene's input/ folder.")
    bytes: int = Field(0, description="Total size of the stored input files.")
    summary: dict[str, Any] = Field(
        default_factory=dict,
        description="What validation found (Gaussian count, frames, camera format, image sizes).",
        examples=[{"gaussians": 12000, "frames": 24, "camera_format": "transforms.json"}],
    )
    pending_uploads: list[dict[str, Any]] = Field(
        default_factory=list, description="Presigned multipart uploads not yet completed."
    )
    created_at: datetime
    updated_at: datetime


class SceneGone(LookupError):
    """The scene has no row, or its row is being deleted."""

    def __init__(self, scene_id: str) -> None:
        super().__init__(f"scene {scene_id!r} not found")
        self.scene_id = scene_id


class SceneNotReady(Exception):
    """A job was asked for on a scene whose upload is not completed."""

    def __init__(self, scene_id: str) -> None:
        super().__init__(f"scene {scene_id!r} is not ready (upload not completed)")
        self.scene_id = scene_id


class SceneNotUploading(Exception):
    """A completion found the scene already past ``uploading`` (an earlier completion won)."""

    def __init__(self, scene_id: str, state: str) -> None:
        super().__init__(f"scene {scene_id!r} is already {state}")
        self.scene_id = scene_id
        self.state = state


class SceneBusy(Exception):
    """A delete was refused: a job on the scene is queued or running."""

    def __init__(self, scene_id: str, job_id: str, job_state: str) -> None:
        super().__init__(f"scene {scene_id!r} has {job_state} job {job_id}")
        self.scene_id = scene_id
        self.job_id = job_id
        self.job_state = job_state


@dataclass(frozen=True)
class DeletingScene:
    """A scene whose delete was acknowledged but whose row is not purged yet (the sweeper's work)."""

    tenant: str
    id: str
    pending_uploads: builtins.list[dict[str, Any]]


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


def _row_of(record: SceneRecord, state: str | None = None) -> dict[str, Any]:
    row = record.model_dump(mode="json")
    row["created_at"], row["updated_at"] = record.created_at, record.updated_at
    row["state"] = state or record.state.value
    return {name: row[name] for name in _FIELDS}


def lock_ready(conn: Connection, tenant: str, scene_ids: Sequence[str]) -> dict[str, SceneRecord]:
    """Share-lock the rows of `scene_ids` in the caller's transaction and return their records.

    Called first in the transaction that inserts jobs on these scenes: the ``FOR SHARE`` locks
    last until the jobs are committed, so `SceneStore.mark_deleting` (``FOR UPDATE``) waits for
    them and then sees the jobs. `SceneGone` names the first scene (in the given order) that has
    no row or is being deleted; `SceneNotReady` one still uploading."""
    wanted = builtins.list(dict.fromkeys(scene_ids))
    if not wanted:
        return {}
    rows = scene_rows.share_lock(conn, tenant, wanted)
    for scene_id in wanted:
        row = rows.get(scene_id)
        if row is None or row["state"] == DELETING:
            raise SceneGone(scene_id)
        if row["state"] != SceneState.ready.value:
            raise SceneNotReady(scene_id)
    return {scene_id: _record_of(rows[scene_id]) for scene_id in wanted}


class SceneStore:
    """Reads and changes scene rows (`records.tables.scenes`) on the records engine."""

    def __init__(self, database: Engine) -> None:
        self.database = database

    def create(self, record: SceneRecord) -> None:
        """Insert a new scene's row (its id is new: a clash is an error)."""
        with records.begin(self.database) as conn:
            scene_rows.insert_row(conn, _row_of(record))

    def adopt(self, record: SceneRecord, *, deleting: bool = False) -> bool:
        """Insert a row for a scene recorded elsewhere (an upgrade's import) unless one exists;
        True when inserted. `deleting`: the scene's delete was acknowledged there."""
        with records.begin(self.database) as conn:
            return scene_rows.insert_if_absent(conn, _row_of(record, DELETING if deleting else None))

    def get(self, tenant: str, scene_id: str) -> SceneRecord | None:
        """The scene's record; None when it has no row or is being deleted."""
        with records.connect(self.database) as conn:
            row = scene_rows.load(conn, tenant, scene_id)
        return None if row is None or row["state"] == DELETING else _record_of(row)

    def list(
        self, tenant: str, limit: int, cursor: str | None = None
    ) -> tuple[builtins.list[SceneRecord], str | None]:
        """A page of the tenant's scenes, newest first (descending id), without deleting ones;
        `cursor` is the last id of the previous page, the second value the next page's cursor."""
        with records.connect(self.database) as conn:
            rows = scene_rows.page(conn, tenant, limit + 1, cursor)
        page = [_record_of(r) for r in rows[:limit]]
        return page, (page[-1].id if len(rows) > limit else None)

    def publish_ready(
        self,
        tenant: str,
        scene_id: str,
        *,
        files: int,
        size: int,
        summary: dict[str, Any],
        while_locked: Callable[[], None] | None = None,
    ) -> SceneRecord:
        """Turn an uploading scene ready (its files, bytes and summary; no pending uploads left),
        in one transaction holding its row ``FOR UPDATE``. `SceneGone` when the row is absent or
        being deleted (a delete came first: the caller removes what it copied);
        `SceneNotUploading` when another completion published it. `while_locked` runs with the
        row locked, before the change (the API's test pause point)."""
        with records.begin(self.database) as conn:
            row = scene_rows.load(conn, tenant, scene_id, lock=True)
            if while_locked is not None:
                while_locked()
            if row is None or row["state"] == DELETING:
                raise SceneGone(scene_id)
            if row["state"] != SceneState.uploading.value:
                raise SceneNotUploading(scene_id, row["state"])
            changed = scene_rows.set_ready(conn, tenant, scene_id, files=files, size=size, summary=summary)
        return _record_of(changed)

    def mark_deleting(self, tenant: str, scene_id: str) -> SceneRecord:
        """Mark the scene deleting, in one transaction holding its row ``FOR UPDATE``, unless a
        job on it is queued or running (`SceneBusy`); `SceneGone` when it has no row or is
        already being deleted. Returns the record as it was (its pending uploads are to abort).
        Once this commits the scene is gone for every reader and for good, and so are its jobs'
        answers (issue 42; the jobs' rows stay: a job's record outlives its scene)."""
        with records.begin(self.database) as conn:
            row = scene_rows.load(conn, tenant, scene_id, lock=True)
            if row is None or row["state"] == DELETING:
                raise SceneGone(scene_id)
            active = job_rows.active_on_scene(conn, tenant, scene_id)
            if active is not None:
                raise SceneBusy(scene_id, active["id"], active["state"])
            scene_rows.set_deleting(conn, tenant, scene_id)
            answer_records.delete_scene(conn, tenant, scene_id)  # gone with the scene, at once
        return _record_of(row)

    def purge(self, tenant: str, scene_id: str) -> None:
        """Drop a deleting scene's row once its objects are gone (a row in any other state stays)."""
        with records.begin(self.database) as conn:
            scene_rows.purge(conn, tenant, scene_id)

    def deleting_scenes(self) -> builtins.list[DeletingScene]:
        """Every scene of every tenant whose delete was acknowledged and whose row remains."""
        with records.connect(self.database) as conn:
            rows = scene_rows.deleting(conn)
        return [DeletingScene(tenant, scene_id, pending) for tenant, scene_id, pending in rows]

    def listed_uploads(self, tenant: str, scene_ids: Sequence[str]) -> dict[str, frozenset[str]]:
        """The scenes of `scene_ids` that have a row (any state), each with the multipart upload
        ids its row lists as pending: one query for a tenant's share of a bucket sweep."""
        if not scene_ids:
            return {}
        with records.connect(self.database) as conn:
            rows = scene_rows.pending_uploads(conn, tenant, scene_ids)
        return {
            scene_id: frozenset(str(p.get("upload_id")) for p in pending)
            for scene_id, pending in rows.items()
        }
