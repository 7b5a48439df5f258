"""Import the scene records that earlier releases kept in the bucket into the `scenes` table.

Why: before scenes became rows (`store`), a scene's record was the object
``tenants/<t>/scenes/<id>/scene.json`` and a delete wrote ``tenants/<t>/tombstones/scenes/<id>``
before removing the scene's objects. A deployment upgraded from such a release has those objects
and no rows, so its scenes would answer 404 and the orphan sweeper would take their files for an
abandoned upload. `bfields-service import-scenes` runs this once after the migration (again is
harmless: a scene that has a row is left as it is):

- every ``scene.json`` becomes a row with the record's fields, under the tenant its key names;
- a scene with a tombstone becomes a ``deleting`` row, which the sweeper finishes at once
  (objects, multipart uploads, then the row);
- nothing in the bucket is changed: the old record objects are inert once the rows exist and go
  with their scene's prefix when it is deleted; the empty listing markers and tombstones outside
  those prefixes are read by nothing and may be removed by the operator (docs/service/records.md).

This is the only module that still reads the old layout; the service never writes it.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field

from pydantic import ValidationError

from bayesian_fields_core.job.store import ArtifactNotFound, Store
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.records.database import open_records
from bayesian_fields_service.sanitize.text import scrub
from bayesian_fields_service.scenes.layout import (
    LEGACY_RECORD_NAME,
    bucket_scenes_of,
    legacy_record_of,
    legacy_tombstone,
)
from bayesian_fields_service.scenes.model import SceneRecord
from bayesian_fields_service.scenes.postgres import scene_store
from bayesian_fields_service.scenes.store import SceneStore
from bayesian_fields_service.storage.stores import TENANTS_ROOT, build_store


@dataclass
class ImportReport:
    """What one import found, scene by scene."""

    imported: int = 0
    deleting: int = 0
    present: int = 0
    unreadable: list[str] = field(default_factory=list)

    def line(self) -> str:
        bad = f": {', '.join(self.unreadable)}" if self.unreadable else ""
        return (
            f"scenes: {self.imported} imported ({self.deleting} of them deleted, left to the sweeper), "
            f"{self.present} already had a row, {len(self.unreadable)} unreadable{bad}"
        )


def run_import(settings: ServiceSettings) -> ImportReport:
    """`import_scenes` on the deployment's bucket and records database (brought to the newest
    schema first unless BFIELDS_MIGRATE_ON_START is off)."""
    database = open_records(settings.database_url, migrate_first=settings.migrate_on_start)
    return import_scenes(build_store(settings), scene_store(database))


def import_scenes(store: Store, scenes: SceneStore) -> ImportReport:
    """Insert a row for every scene record object in the bucket that has none (idempotent)."""
    report = ImportReport()
    for tenant, scene_id, key in _record_keys(store):
        try:
            raw = store.get_bytes(key)
        except ArtifactNotFound:
            continue  # a scene folder without a record: an orphan the sweeper judges by its age
        record = _parsed(raw, tenant, scene_id)
        if record is None:
            report.unreadable.append(key)
            continue
        deleting = store.exists(legacy_tombstone(tenant, scene_id))
        if scenes.adopt(record, deleting=deleting):
            report.imported += 1
            report.deleting += deleting
        else:
            report.present += 1
    return report


def _record_keys(store: Store) -> Iterator[tuple[str, str, str]]:
    """(tenant, scene id, key of its record object) of every scene folder in the bucket. On S3
    a listing of folders, not of every object (uploads and results are most of a bucket); a
    local folder store is listed whole."""
    from bayesian_fields_service.storage.s3_store import S3Store  # boto3: only S3 deployments have it

    if isinstance(store, S3Store):
        for tenant_root in store.list_prefixes(f"{TENANTS_ROOT}/"):
            for scene_root in store.list_prefixes(bucket_scenes_of(tenant_root)):
                parts = scene_root.split("/")
                yield parts[1], parts[3], scene_root + LEGACY_RECORD_NAME
        return
    for key in store.list(f"{TENANTS_ROOT}/"):
        found = legacy_record_of(key)
        if found is not None:
            yield found[0], found[1], key


def _parsed(raw: bytes, tenant: str, scene_id: str) -> SceneRecord | None:
    """The record, under the tenant and id its key names; None when it is not a valid record
    (scrubbed first: a record stored before the API refused lone surrogates is still read)."""
    try:
        return SceneRecord.model_validate({**scrub(json.loads(raw)), "tenant": tenant, "id": scene_id})
    except (ValueError, ValidationError, TypeError):
        return None
