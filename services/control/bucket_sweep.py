"""Remove from the bucket what a killed API process or a half-done delete left, and nothing else.

A presigned upload starts S3 multipart uploads before its scene record is written, and a
single-request upload copies the scene into the bucket before it writes the record, so a SIGKILL
(OOM killer, node loss) in between leaves objects no API call can see or delete:
- multipart uploads under ``tenants/<t>/scenes/<id>/staging/`` that no scene record lists in its
  ``pending_uploads`` (the record was never written);
- scene files under ``tenants/<t>/scenes/<id>/`` with no record (a single-request upload killed
  while it copied the scene into the bucket);
- whatever is left of a *deleted* scene (see `api.scene_lifecycle`): a delete that failed
  half-way, or a completion that copied files after the delete listed them. These go at once,
  whatever their age: nothing may write a deleted scene.

Everything else is removed only when older than BFIELDS_ORPHAN_MAX_AGE_S (since its newest
write), so an upload in progress is never touched; scenes that have a record, including those
still ``uploading``, are their tenant's and are left alone. The control process's leader runs
this every BFIELDS_ORPHAN_SWEEP_INTERVAL_S (one sweep per deployment); each API process sweeps
only its own upload temp folders (`api.sweeper`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from bayesian_fields_core.job.store import ArtifactNotFound, get_json


@dataclass
class BucketSweep:
    """What one bucket sweep removed (full keys)."""

    aborted_uploads: list[str] = field(default_factory=list)
    deleted_prefixes: list[str] = field(default_factory=list)


def _age_s(stamp: Any, now: float) -> float:
    return now - stamp.timestamp()


def sweep_bucket(store: Any, max_age_s: float, *, now: float | None = None) -> BucketSweep:
    """Abort multipart uploads and delete scene prefixes that no scene record names, when older
    than `max_age_s`. `store` is the bucket's `S3Store` (needs list_prefixes, list_objects,
    list_multipart_uploads)."""
    now = time.time() if now is None else now
    out = BucketSweep()
    records: dict[str, dict | None] = {}
    tombstoned: dict[str, bool] = {}

    def deleted(scene_root: str) -> bool:  # tenants/<t>/scenes/<id>/ -> tenants/<t>/tombstones/...
        if scene_root not in tombstoned:
            tenant_root, _, scene_id = scene_root.rstrip("/").rpartition("/scenes/")
            tombstoned[scene_root] = store.exists(f"{tenant_root}/tombstones/scenes/{scene_id}")
        return tombstoned[scene_root]

    def record(scene_root: str) -> dict | None:  # scene_root = tenants/<t>/scenes/<id>/
        if scene_root not in records:
            try:
                records[scene_root] = get_json(store, scene_root + "scene.json")
            except ArtifactNotFound:
                records[scene_root] = None
        return records[scene_root]

    for up in store.list_multipart_uploads("tenants/"):
        parts = up.key.split("/")
        if len(parts) < 5 or parts[2] != "scenes":
            continue
        scene_root = "/".join(parts[:4]) + "/"
        if deleted(scene_root):
            store.abort_multipart_upload(up.key, up.upload_id)
            out.aborted_uploads.append(up.key)
            continue
        if _age_s(up.initiated, now) < max_age_s:
            continue
        rec = record(scene_root)
        listed = rec is not None and any(
            p.get("upload_id") == up.upload_id for p in rec.get("pending_uploads", [])
        )
        if not listed:
            store.abort_multipart_upload(up.key, up.upload_id)
            out.aborted_uploads.append(up.key)
    for tenant_root in store.list_prefixes("tenants/"):
        for scene_root in store.list_prefixes(tenant_root + "scenes/"):
            if deleted(scene_root):
                store.delete_prefix(scene_root)
                scene_id = scene_root.rstrip("/").rpartition("/")[2]
                store.delete(f"{tenant_root}index/scenes/{scene_id}")
                out.deleted_prefixes.append(scene_root)
                continue
            if record(scene_root) is not None:
                continue
            objects = store.list_objects(scene_root)
            if not objects or any(o.key.endswith("/scene.json") for o in objects):
                continue  # written meanwhile
            if min(_age_s(o.last_modified, now) for o in objects) < max_age_s:
                continue  # still being written
            store.delete_prefix(scene_root)
            out.deleted_prefixes.append(scene_root)
    return out
