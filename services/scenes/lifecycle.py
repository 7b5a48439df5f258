"""A scene's life: uploading -> ready, or deleted for good; what keeps it so across requests.

Why: `complete` (minutes: assemble, validate, copy into the bucket) and `delete` (mark, then a
listing and a batch delete) run side by side. A delete that answered 204 while a completion was
still copying files once let the completion publish its record afterwards: a deleted scene came
back, sometimes with only part of its files. Rules now (the scene's row, `store`):

- **The row decides.** `delete` first marks the row ``deleting`` (committed before anything is
  removed), then aborts the scene's multipart uploads, removes its objects and purges the row.
  From the mark on the scene is gone for every route (404), whatever objects are still on their
  way out, and what a delete that stopped half-way leaves, the sweeper removes
  (`bucket_sweep.sweep_bucket`). Ids are never reused, so a purged row never hides a new scene.
- **Row locks order the deciding steps.** `complete` publishes the ready record in one
  transaction holding the row ``FOR UPDATE``; `delete` marks it in one, after checking for active
  jobs; a job submission holds the row ``FOR SHARE`` until its jobs are committed. So a delete
  either comes before the ready record (the completion finds the row deleting or gone, removes
  what it copied and answers 404) or after it (the delete removes the complete scene), and a job
  is either committed before the delete looks for active jobs (409) or refused because the row
  says deleting (404).
- **Completion claim.** One `complete` per scene at a time (409 for a second), so two
  completions never interleave their copies (`ports.SceneRecords.completion_claim`).
- **The row last.** A single-request upload inserts its row once every file is in the bucket,
  and a presigned one once its multipart uploads exist: a process killed between the steps
  leaves objects no row names, which the bucket sweep removes once they are old.

The named points (`hooks.point`) let the race tests hold a request between two steps.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import ArtifactNotFound, PrefixedStore, Store
from bayesian_fields_service import hooks
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.scenes.intake import (
    UploadedFile,
    alignment_wanted,
    checked_name,
    clean_filename,
    ingest,
)
from bayesian_fields_service.scenes.layout import scene_root, staging_key, staging_prefix
from bayesian_fields_service.scenes.model import SceneRecord, SceneState
from bayesian_fields_service.scenes.refusals import (
    DeletedMeanwhile,
    NoDirectUploads,
    SceneGone,
    SceneNotUploading,
    UploadTooLarge,
    UploadVanished,
)
from bayesian_fields_service.scenes.store import SceneStore
from bayesian_fields_service.scenes.upload_temp import workdir
from bayesian_fields_service.storage.stores import (
    DirectTransfers,
    TenantTransfers,
    direct_transfers,
    tenant_store,
)

#: Parts of a presigned upload, as a client reports them: {file name: [{PartNumber, ETag}, ...]}.
Parts = dict[str, list[dict[str, Any]]]


@dataclass(frozen=True)
class FileToSend:
    """One file a presigned upload announces: its role, name and exact size."""

    field: str
    name: str
    size: int


@dataclass(frozen=True)
class StartedFile:
    """One started multipart upload: where the client sends each part."""

    field: str
    name: str
    upload_id: str
    part_size: int
    part_urls: list[str]


@dataclass(frozen=True)
class StartedUpload:
    scene_id: str
    uploads: list[StartedFile]
    expires_in_s: int


@dataclass
class Scenes:
    """The scenes domain as the API calls it: each method one request's rules and ordering.

    `bucket` is the whole store (each tenant sees its part, `storage.stores.tenant_store`);
    `transfers` its direct transfers (presigned multipart uploads), None where it has none (a
    local folder; the tests may hand in another); `new_id` makes a new scene id (``s_`` +
    time-ordered digits, `common.jobs.new_id`); `clock` the records' times."""

    settings: ServiceSettings
    bucket: Store
    rows: SceneStore
    new_id: Callable[[], str]
    transfers: DirectTransfers | None = field(default=None)
    clock: Callable[[], datetime] = field(default=lambda: datetime.now(UTC))

    def __post_init__(self) -> None:
        if self.transfers is None:
            self.transfers = direct_transfers(self.bucket)

    def tenant(self, tenant: str) -> PrefixedStore:
        return tenant_store(self.bucket, tenant)

    def _transfers(self, tenant: str) -> TenantTransfers:
        if self.transfers is None:
            raise NoDirectUploads
        return TenantTransfers(self.transfers, self.tenant(tenant), self.settings.presign_expiry_s)

    def workdir(self, kind: str) -> AbstractContextManager[Path]:
        """A temp folder for one request (``upload`` or ``complete``), removed when it ends."""
        return workdir(kind)

    # reads

    def get(self, tenant: str, scene_id: str) -> SceneRecord:
        """The tenant's scene; `SceneGone` when it has no row or is being deleted."""
        record = self.rows.get(tenant, scene_id)
        if record is None:
            raise SceneGone(scene_id)
        return record

    def page(self, tenant: str, limit: int, cursor: str | None) -> tuple[list[SceneRecord], str | None]:
        """A page of the tenant's scenes, newest first, and the next page's cursor."""
        return self.rows.list(tenant, limit, cursor)

    def _deleted(self, tenant: str, scene_id: str) -> bool:
        """Whether the scene's delete was acknowledged (its row says deleting, or is purged)."""
        return self.rows.get(tenant, scene_id) is None

    # a single-request upload

    def upload(
        self, tenant: str, files: Sequence[UploadedFile], fields: dict[str, str], work: Path
    ) -> SceneRecord:
        """Lay out, validate and store an uploaded scene (files already in `work`), then insert
        its row: nothing is stored when any check fails (`InputError`). Blocking."""
        scene_id = self.new_id()
        alignment = alignment_wanted(fields.get("alignment_check"))
        n, size, summary = ingest(
            self.settings, self.tenant(tenant), scene_id, files, work, alignment=alignment
        )
        now = self.clock()
        record = SceneRecord(
            id=scene_id, tenant=tenant, name=checked_name(fields.get("name")), files=n, bytes=size,
            summary=summary, created_at=now, updated_at=now,
        )  # fmt: skip
        self.rows.create(record)  # the row last (module docstring)
        return record

    # a presigned upload: start, then complete

    def start_upload(self, tenant: str, name: str | None, files: Sequence[FileToSend]) -> StartedUpload:
        """Start one multipart upload per file under the scene's ``staging/`` and insert the
        scene's row as ``uploading`` listing them. `NoDirectUploads`, `UploadTooLarge`, or an
        InputError naming the file whose name or size cannot be uploaded."""
        name = checked_name(name)  # before anything is started in the bucket
        transfers = self._transfers(tenant)
        total = sum(f.size for f in files)
        if total > self.settings.max_upload_bytes:
            raise UploadTooLarge(total, self.settings.max_upload_bytes)
        from bayesian_fields_service.storage.s3_store import plan_parts  # only with direct transfers

        scene_id = self.new_id()
        part_size = self.settings.s3_multipart_chunk_bytes
        started, pending = [], []
        for spec in files:
            file_name = clean_filename(spec.name, field_name=spec.field)
            key = staging_key(scene_id, spec.field, file_name)
            parts = plan_parts(spec.size, part_size)
            upload_id = transfers.start(key)
            urls = [transfers.part_link(key, upload_id, p.part_number) for p in parts]
            started.append(StartedFile(spec.field, file_name, upload_id, part_size, urls))
            pending.append({"field": spec.field, "name": file_name, "key": key, "upload_id": upload_id,
                            "size": spec.size})  # fmt: skip
        now = self.clock()
        record = SceneRecord(
            id=scene_id, tenant=tenant, name=name, state=SceneState.uploading,
            pending_uploads=pending, created_at=now, updated_at=now,
        )  # fmt: skip
        self.rows.create(record)  # after the uploads exist: the sweeper aborts those no row lists
        return StartedUpload(scene_id, started, self.settings.presign_expiry_s)

    def complete(
        self, tenant: str, scene_id: str, parts: Parts | None = None, *, alignment: bool = True
    ) -> SceneRecord:
        """Finish the multipart uploads, validate, copy the scene to ``input/``, then (holding
        the scene's row, unless a delete came first) publish the ready record (module docstring).
        `parts`: the ETags per file name a client kept (None: the bucket lists them)."""
        with self.rows.completion_claim(tenant, scene_id):
            record = self.get(tenant, scene_id)  # under the claim: no other completion runs now
            if record.state != SceneState.uploading:
                raise SceneNotUploading(scene_id, record.state.value)
            try:
                n, size, summary = self._complete_files(tenant, record, parts, alignment)
            except BaseException:
                if self._deleted(tenant, scene_id):
                    # a delete listed the scene's objects while this completion was still
                    # assembling them: a file finished after that listing would stay behind. The
                    # delete is final (the row's state), so everything under the scene is removed
                    # here, after the last write.
                    self.tenant(tenant).delete_prefix(scene_root(scene_id))
                raise
            return self._publish(tenant, record, n, size, summary)

    def _complete_files(
        self, tenant: str, record: SceneRecord, parts: Parts | None, alignment: bool
    ) -> tuple[int, int, dict[str, Any]]:
        """Finish the multipart uploads, fetch, validate and copy the scene into ``input/``."""
        scene_id = record.id
        ts = self.tenant(tenant)
        transfers = self._transfers(tenant)  # none: no multipart upload can have been started
        with self.workdir("complete") as work:
            try:
                hooks.point("scene.complete.claimed", scene_id=scene_id)
                files = []
                for i, up in enumerate(record.pending_uploads):
                    self._finish_file(
                        tenant, scene_id, transfers, up, None if parts is None else parts.get(up["name"])
                    )
                    actual = ts.size(up["key"])
                    if actual != up["size"]:
                        raise InputError(
                            f"uploaded {actual} bytes, announced {up['size']}", source=up["name"]
                        )
                    local = work / "parts" / f"part-{i:05d}"
                    ts.get_file(up["key"], local)
                    files.append(UploadedFile(up["field"], up["name"], local))
                hooks.point("scene.complete.fetched", scene_id=scene_id)
                if self._deleted(
                    tenant, scene_id
                ):  # deleted meanwhile: skip the copy (publishing checks again)
                    raise DeletedMeanwhile(scene_id)
                return ingest(self.settings, ts, scene_id, files, work, alignment=alignment)
            except ArtifactNotFound:  # a staged object vanished: only a delete removes them
                if self._deleted(tenant, scene_id):
                    raise DeletedMeanwhile(scene_id) from None
                raise

    def _finish_file(
        self, tenant: str, scene_id: str, transfers: TenantTransfers, up: dict[str, Any],
        parts: list[dict[str, Any]] | None,
    ) -> None:  # fmt: skip
        """Complete one file's multipart upload. Resumable: a file an earlier, failed completion
        finished (its object exists with the announced size) is taken as done, instead of stuck
        on NoSuchUpload for good."""
        try:
            transfers.complete(up["key"], up["upload_id"], parts)
        except (InputError, ArtifactNotFound) as exc:
            if self._deleted(tenant, scene_id):
                raise DeletedMeanwhile(scene_id) from None
            if _assembled(self.tenant(tenant), up):
                return
            if isinstance(exc, ArtifactNotFound):  # the upload id is no longer known
                raise UploadVanished(up["name"]) from None
            raise

    def _publish(
        self, tenant: str, record: SceneRecord, n: int, size: int, summary: dict[str, Any]
    ) -> SceneRecord:
        """Make the record ready unless the scene was deleted meanwhile (then remove the copy:
        `DeletedMeanwhile`): the state check and the change are one transaction holding the
        scene's row, which `delete` needs to mark the scene deleting."""
        scene_id = record.id
        ts = self.tenant(tenant)
        hooks.point("scene.complete.before_publish", scene_id=scene_id)
        try:
            ready = self.rows.publish_ready(
                tenant, scene_id, files=n, size=size, summary=summary,
                while_locked=lambda: hooks.point("scene.complete.publishing", scene_id=scene_id),
            )  # fmt: skip
        except SceneGone:  # deleted after the copy began: what it copied goes too
            ts.delete_prefix(scene_root(scene_id))
            raise DeletedMeanwhile(scene_id) from None
        ts.delete_prefix(staging_prefix(scene_id))
        return ready

    # delete

    def delete(self, tenant: str, scene_id: str) -> None:
        """Mark the scene deleting (refused while a job on it is queued or running: `SceneBusy`),
        then abort its multipart uploads, remove its objects and drop its row. Once the mark is
        committed the scene is gone for every route and for good; what a failure after it leaves
        behind, the sweeper removes."""
        record = self.rows.mark_deleting(tenant, scene_id)
        hooks.point("scene.delete.marked", scene_id=scene_id)
        if self.transfers is not None:  # a backend without them has no multipart upload to abort
            transfers = self._transfers(tenant)
            for up in record.pending_uploads:
                transfers.abort(up["key"], up["upload_id"])
        self.tenant(tenant).delete_prefix(scene_root(scene_id))
        self.rows.purge(tenant, scene_id)


def _assembled(ts: PrefixedStore, up: dict[str, Any]) -> bool:
    """Whether a file's multipart upload was already completed: its object exists with the
    announced size."""
    try:
        return ts.size(up["key"]) == up["size"]
    except ArtifactNotFound:
        return False
