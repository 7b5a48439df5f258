"""The rules over scene rows: a row of the `scenes` table is the truth about a scene; its files
stay in the bucket under ``tenants/<t>/scenes/<id>/`` (`layout`).

Why rows: a scene's fate is decided by three requests that may race (`complete` publishing the
upload, `delete`, a job submission on the scene). In the bucket that took a record object, index
markers, deletion marks and advisory locks kept in step by hand; as rows, the scene's own row lock
orders them and its state says what happened:

- ``uploading`` (a presigned upload not yet completed) -> ``ready`` (`SceneStore.publish_ready`,
  holding the row for update) -> ``deleting`` (`SceneStore.mark_deleting`, holding it, refused
  while a job on the scene is queued or running) -> no row (`SceneStore.purge`, once the scene's
  objects are gone). A ``deleting`` row is gone for every reader (`get` and `list` skip it), and
  no step turns it back: an acknowledged delete is final by the row's state. What a delete that
  stopped half-way leaves, the orphan sweeper finishes (`deleting_scenes`).
- A job submission calls `ready_scenes` (`postgres.lock_ready`) in the transaction that inserts
  its jobs: the scenes' rows held shared until the jobs are committed. So a delete either waits
  for the submission and then sees its active job (refused), or comes first and the submission
  sees ``deleting`` (`SceneGone`).

The rules are written against `ports.SceneRecords`, so they run the same on PostgreSQL and on
the tests' in-memory fake.
"""

from __future__ import annotations

import builtins
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from typing import Any

from bayesian_fields_service.scenes.model import DeletingScene, SceneRecord, SceneState
from bayesian_fields_service.scenes.ports import SceneRecords, SceneRows
from bayesian_fields_service.scenes.refusals import SceneBusy, SceneGone, SceneNotReady, SceneNotUploading


def ready_scenes(rows: SceneRows, tenant: str, scene_ids: Sequence[str]) -> dict[str, SceneRecord]:
    """Share-lock the rows of `scene_ids` in the caller's unit of work and return their records.

    `SceneGone` names the first scene (in the given order) that has no row or is being deleted;
    `SceneNotReady` one still uploading."""
    wanted = builtins.list(dict.fromkeys(scene_ids))
    if not wanted:
        return {}
    found = rows.share_lock(tenant, wanted)
    ready: dict[str, SceneRecord] = {}
    for scene_id in wanted:
        row = found.get(scene_id)
        if not isinstance(row, SceneRecord):
            raise SceneGone(scene_id)
        if row.state != SceneState.ready:
            raise SceneNotReady(scene_id)
        ready[scene_id] = row
    return ready


class SceneStore:
    """Reads and changes scene rows through the records port, each change one unit of work."""

    def __init__(self, records: SceneRecords) -> None:
        self.records = records

    def completion_claim(self, tenant: str, scene_id: str) -> AbstractContextManager[None]:
        """One completion of the scene at a time (`refusals.CompletionBusy` for another)."""
        return self.records.completion_claim(tenant, scene_id)

    def create(self, record: SceneRecord) -> None:
        """Insert a new scene's row (its id is new: a clash is an error)."""
        with self.records.transaction() as rows:
            rows.insert(record)

    def adopt(self, record: SceneRecord, *, deleting: bool = False) -> bool:
        """Insert a row for a scene recorded elsewhere (an upgrade's import) unless one exists;
        True when inserted. `deleting`: the scene's delete was acknowledged there."""
        with self.records.transaction() as rows:
            return rows.adopt(record, deleting=deleting)

    def get(self, tenant: str, scene_id: str) -> SceneRecord | None:
        """The scene's record; None when it has no row or is being deleted."""
        with self.records.read() as rows:
            row = rows.load(tenant, scene_id)
        return row if isinstance(row, SceneRecord) else None

    def list(
        self, tenant: str, limit: int, cursor: str | None = None
    ) -> tuple[builtins.list[SceneRecord], str | None]:
        """A page of the tenant's scenes, newest first (descending id), without deleting ones;
        `cursor` is the last id of the previous page, the second value the next page's cursor."""
        with self.records.read() as rows:
            found = rows.page(tenant, limit + 1, cursor)
        page = found[:limit]
        return page, (page[-1].id if len(found) > limit else None)

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
        in one unit of work holding its row for update. `SceneGone` when the row is absent or
        being deleted (a delete came first: the caller removes what it copied);
        `SceneNotUploading` when another completion published it. `while_locked` runs with the
        row locked, before the change (the tests' pause point)."""
        with self.records.transaction() as rows:
            row = rows.load(tenant, scene_id, lock=True)
            if while_locked is not None:
                while_locked()
            if not isinstance(row, SceneRecord):
                raise SceneGone(scene_id)
            if row.state != SceneState.uploading:
                raise SceneNotUploading(scene_id, row.state.value)
            return rows.set_ready(tenant, scene_id, files=files, size=size, summary=summary)

    def mark_deleting(self, tenant: str, scene_id: str) -> SceneRecord:
        """Mark the scene deleting, in one unit of work holding its row for update, unless a
        job on it is queued or running (`SceneBusy`); `SceneGone` when it has no row or is
        already being deleted. Returns the record as it was (its pending uploads are to abort).
        Once this commits the scene is gone for every reader and for good, and so are its jobs'
        answers (issue 42; the jobs' rows stay: a job's record outlives its scene)."""
        with self.records.transaction() as rows:
            row = rows.load(tenant, scene_id, lock=True)
            if not isinstance(row, SceneRecord):
                raise SceneGone(scene_id)
            active = rows.active_job(tenant, scene_id)
            if active is not None:
                raise SceneBusy(scene_id, *active)
            rows.set_deleting(tenant, scene_id)
            rows.drop_answers(tenant, scene_id)  # gone with the scene, at once
        return row

    def purge(self, tenant: str, scene_id: str) -> None:
        """Drop a deleting scene's row once its objects are gone (a row in any other state stays)."""
        with self.records.transaction() as rows:
            rows.purge(tenant, scene_id)

    def deleting_scenes(self) -> builtins.list[DeletingScene]:
        """Every scene of every tenant whose delete was acknowledged and whose row remains."""
        with self.records.read() as rows:
            return rows.deleting()

    def listed_uploads(self, tenant: str, scene_ids: Sequence[str]) -> dict[str, frozenset[str]]:
        """The scenes of `scene_ids` that have a row (any state), each with the multipart upload
        ids its row lists as pending: one query for a tenant's share of a bucket sweep."""
        if not scene_ids:
            return {}
        with self.records.read() as rows:
            found = rows.pending_uploads(tenant, scene_ids)
        return {
            scene_id: frozenset(str(p.get("upload_id")) for p in pending)
            for scene_id, pending in found.items()
        }
