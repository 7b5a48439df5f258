"""In-memory fakes of the scenes domain's ports, so its rules run in the inner loop.

`InMemorySceneRecords` is the records port (`scenes.ports.SceneRecords`) as a dict: a
transaction works on a copy and publishes it only when the block ends without an error (so a
refused change leaves nothing, as PostgreSQL's rollback does); row locks are not modelled (one
thread: the orderings across requests stay the real-stack tests' business,
tests/services/api/test_scene_races.py). `FolderMultipart` is the bucket's multipart uploads
(`storage.stores.DirectTransfers`) over a real `LocalStore`: parts are held until `complete`
writes the object, the way S3 shows no object before it.
"""

from __future__ import annotations

import contextlib
import copy
import itertools
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import ArtifactNotFound, Store
from bayesian_fields_service.scenes.model import DeletingScene, SceneRecord, SceneRow, SceneState
from bayesian_fields_service.scenes.refusals import CompletionBusy


@dataclass
class _Tables:
    scenes: dict[tuple[str, str], SceneRow] = field(default_factory=dict)
    #: (tenant, scene id) -> (job id, job state) of a queued or running job on the scene
    active_jobs: dict[tuple[str, str], tuple[str, str]] = field(default_factory=dict)
    #: (tenant, scene id) -> answers of the scene's jobs (any values; a delete drops them)
    answers: dict[tuple[str, str], list[Any]] = field(default_factory=dict)


class InMemorySceneRows:
    """`scenes.ports.SceneRows` over one `_Tables`."""

    def __init__(self, tables: _Tables) -> None:
        self.t = tables

    def insert(self, record: SceneRecord) -> None:
        key = (record.tenant, record.id)
        if key in self.t.scenes:
            raise KeyError(f"scene {record.id} exists")  # the primary key's clash
        self.t.scenes[key] = record

    def adopt(self, record: SceneRecord, *, deleting: bool) -> bool:
        key = (record.tenant, record.id)
        if key in self.t.scenes:
            return False
        self.t.scenes[key] = (
            DeletingScene(record.tenant, record.id, record.pending_uploads) if deleting else record
        )
        return True

    def load(self, tenant: str, scene_id: str, *, lock: bool = False) -> SceneRow | None:
        return self.t.scenes.get((tenant, scene_id))

    def share_lock(self, tenant: str, scene_ids: Sequence[str]) -> dict[str, SceneRow]:
        return {i: self.t.scenes[(tenant, i)] for i in scene_ids if (tenant, i) in self.t.scenes}

    def page(self, tenant: str, limit: int, before: str | None) -> list[SceneRecord]:
        rows = [
            r for (t, i), r in self.t.scenes.items()
            if t == tenant and isinstance(r, SceneRecord) and (before is None or i < before)
        ]  # fmt: skip
        return sorted(rows, key=lambda r: r.id, reverse=True)[:limit]

    def set_ready(
        self, tenant: str, scene_id: str, *, files: int, size: int, summary: dict[str, Any]
    ) -> SceneRecord:
        row = self.t.scenes[(tenant, scene_id)]
        assert isinstance(row, SceneRecord)
        ready = row.model_copy(update={"state": SceneState.ready, "files": files, "bytes": size, "summary": summary,
                                       "pending_uploads": []})  # fmt: skip
        self.t.scenes[(tenant, scene_id)] = ready
        return ready

    def set_deleting(self, tenant: str, scene_id: str) -> None:
        row = self.t.scenes[(tenant, scene_id)]
        self.t.scenes[(tenant, scene_id)] = DeletingScene(tenant, scene_id, list(row.pending_uploads))

    def purge(self, tenant: str, scene_id: str) -> None:
        if isinstance(self.t.scenes.get((tenant, scene_id)), DeletingScene):
            del self.t.scenes[(tenant, scene_id)]

    def deleting(self) -> list[DeletingScene]:
        return sorted((r for r in self.t.scenes.values() if isinstance(r, DeletingScene)), key=lambda r: r.id)

    def pending_uploads(self, tenant: str, scene_ids: Sequence[str]) -> dict[str, list[dict[str, Any]]]:
        return {
            i: list(self.t.scenes[(tenant, i)].pending_uploads)
            for i in scene_ids
            if (tenant, i) in self.t.scenes
        }

    def active_job(self, tenant: str, scene_id: str) -> tuple[str, str] | None:
        return self.t.active_jobs.get((tenant, scene_id))

    def drop_answers(self, tenant: str, scene_id: str) -> None:
        self.t.answers.pop((tenant, scene_id), None)


class InMemorySceneRecords:
    """`scenes.ports.SceneRecords` in memory (module docstring)."""

    def __init__(self) -> None:
        self.tables = _Tables()
        self.claims: set[tuple[str, str]] = set()

    @contextlib.contextmanager
    def transaction(self) -> Iterator[InMemorySceneRows]:
        work = copy.deepcopy(self.tables)
        yield InMemorySceneRows(work)
        self.tables = work  # only when the block ended without an error: a rollback otherwise

    @contextlib.contextmanager
    def read(self) -> Iterator[InMemorySceneRows]:
        yield InMemorySceneRows(copy.deepcopy(self.tables))

    @contextlib.contextmanager
    def completion_claim(self, tenant: str, scene_id: str) -> Iterator[None]:
        if (tenant, scene_id) in self.claims:
            raise CompletionBusy(scene_id)
        self.claims.add((tenant, scene_id))
        try:
            yield
        finally:
            self.claims.discard((tenant, scene_id))


class FolderMultipart:
    """The bucket's multipart uploads (`DirectTransfers`) over a real folder store (module
    docstring). `send_part` is what a client's PUT to a part link does."""

    def __init__(self, store: Store) -> None:
        self.store = store
        self.uploads: dict[str, tuple[str, dict[int, bytes]]] = {}  # upload id -> (key, parts)
        self.aborted: list[str] = []
        self._ids = itertools.count(1)

    def presigned_get(self, key: str, expires_s: int = 3600, *, filename: str | None = None) -> str:
        return f"folder://{key}"

    def create_multipart_upload(self, key: str, *, content_type: str | None = None) -> str:
        upload_id = f"up-{next(self._ids)}"
        self.uploads[upload_id] = (key, {})
        return upload_id

    def presigned_upload_part(self, key: str, upload_id: str, part_number: int, expires_s: int = 3600) -> str:
        return f"folder://{key}?uploadId={upload_id}&partNumber={part_number}"

    def send_part(self, upload_id: str, part_number: int, data: bytes) -> str:
        self.uploads[upload_id][1][part_number] = data
        return f'"etag-{upload_id}-{part_number}"'

    def complete_multipart_upload(
        self, key: str, upload_id: str, parts: list[dict[str, Any]] | None = None
    ) -> None:
        if upload_id not in self.uploads or self.uploads[upload_id][0] != key:
            raise ArtifactNotFound(f"no such upload: {key}")
        held = self.uploads[upload_id][1]
        numbers = sorted(held) if parts is None else [p["PartNumber"] for p in parts]
        if any(n not in held for n in numbers):
            raise InputError(
                f"part {next(n for n in numbers if n not in held)} was never uploaded", source=key
            )
        self.store.put_bytes(key, b"".join(held[n] for n in numbers))
        del self.uploads[upload_id]

    def abort_multipart_upload(self, key: str, upload_id: str) -> None:
        self.uploads.pop(upload_id, None)
        self.aborted.append(upload_id)
