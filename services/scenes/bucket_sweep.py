"""Remove from the bucket what a killed API process or a half-done delete left, and nothing else.

A single-request upload copies the scene into the bucket and only then inserts its scene's row; a
presigned upload starts S3 multipart uploads before its row is inserted. A SIGKILL (OOM killer,
node loss) between those steps leaves objects no API call can see or delete:
- multipart uploads under ``tenants/<t>/scenes/<id>/staging/`` that no scene row lists in its
  ``pending_uploads`` (the row was never inserted);
- scene files under ``tenants/<t>/scenes/<id>/`` with no scene row (a single-request upload
  killed while it copied the scene into the bucket, or a completion that copied files after a
  delete had finished and whose process died before it could remove them);
- whatever is left of a scene whose row says ``deleting`` (`store`) and its multipart
  uploads: a delete that stopped after its mark. These go at once, whatever their age, and the
  row is purged: nothing may write a scene whose delete was acknowledged.

A scene folder that still holds an earlier release's record object and has no row is kept, with a
warning: it is a scene of a deployment upgraded without `bfields-service import-scenes`
(`legacy_import`), not an orphan.

The others go only when older than BFIELDS_ORPHAN_MAX_AGE_S (since their newest write), so an
upload in progress is never touched; scenes that have a row, including those still
``uploading``, are their tenant's and are left alone. The control process's leader runs this
every BFIELDS_ORPHAN_SWEEP_INTERVAL_S (one sweep per deployment); each API process sweeps only
its own upload temp folders (`upload_temp`).

Which objects are orphans is decided by `orphaned_upload` and `root_verdict` (plain functions of
what the listings and the rows say, tested without a bucket); `sweep_bucket` lists and acts.
"""

from __future__ import annotations

import logging
import time
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from bayesian_fields_service.scenes.layout import (
    LEGACY_RECORD_NAME,
    bucket_scene_root,
    bucket_scenes_of,
    scene_of,
)
from bayesian_fields_service.scenes.store import SceneStore
from bayesian_fields_service.storage.stores import TENANTS_ROOT

log = logging.getLogger(__name__)


@dataclass
class BucketSweep:
    """What one bucket sweep removed (full keys)."""

    aborted_uploads: list[str] = field(default_factory=list)
    deleted_prefixes: list[str] = field(default_factory=list)


def _age_s(stamp: Any, now: float) -> float:
    return now - stamp.timestamp()


class Verdict(StrEnum):
    """What the sweep does with a scene prefix that no deleting row named."""

    keep = "keep"  # a row names the scene (any state): its tenant's
    young = "young"  # written to within the age: an upload may still be copying
    legacy = "legacy"  # an earlier release's record and no row: import it, never delete it
    orphan = "orphan"  # no row, old, not legacy: delete


def orphaned_upload(upload_id: str, listed: frozenset[str], age_s: float, max_age_s: float) -> bool:
    """Whether a multipart upload under a scene is to abort: old enough, and not among the upload
    ids its scene's row lists as pending (`listed`; empty when the scene has no row)."""
    return age_s >= max_age_s and upload_id not in listed


def root_verdict(root: str, has_row: bool, objects: Sequence[tuple[str, float]], max_age_s: float) -> Verdict:
    """The verdict on a scene prefix `root` from whether a row names it and its objects (key,
    age in s): an empty prefix or one with a write younger than `max_age_s` is young."""
    if has_row:
        return Verdict.keep
    if not objects or min(age for _, age in objects) < max_age_s:
        return Verdict.young
    if any(key == root + LEGACY_RECORD_NAME for key, _ in objects):
        return Verdict.legacy
    return Verdict.orphan


def sweep_bucket(
    store: Any, scenes: SceneStore, max_age_s: float, *, now: float | None = None
) -> BucketSweep:
    """Finish the deletes that stopped half-way, then abort multipart uploads and delete scene
    prefixes that no scene row names, when older than `max_age_s` (module docstring). `store` is
    the bucket's `S3Store` (needs list_prefixes, list_objects, list_multipart_uploads); `scenes`
    the scene rows."""
    now = time.time() if now is None else now
    out = BucketSweep()
    finished: set[str] = set()
    for scene in scenes.deleting_scenes():  # acknowledged deletes: at once, whatever the age
        root = bucket_scene_root(scene.tenant, scene.id)
        for up in store.list_multipart_uploads(root):
            store.abort_multipart_upload(up.key, up.upload_id)
            out.aborted_uploads.append(up.key)
        store.delete_prefix(root)
        scenes.purge(scene.tenant, scene.id)
        out.deleted_prefixes.append(root)
        finished.add(root)

    old_uploads: dict[str, list[tuple[str, Any]]] = defaultdict(list)  # tenant -> (scene, upload)
    for up in store.list_multipart_uploads(f"{TENANTS_ROOT}/"):
        where = scene_of(up.key)
        if where is not None and _age_s(up.initiated, now) >= max_age_s:
            old_uploads[where[0]].append((where[1], up))
    for tenant, uploads in old_uploads.items():
        listed = scenes.listed_uploads(tenant, sorted({scene_id for scene_id, _ in uploads}))
        for scene_id, up in uploads:
            age_s = _age_s(up.initiated, now)
            if orphaned_upload(up.upload_id, listed.get(scene_id, frozenset()), age_s, max_age_s):
                store.abort_multipart_upload(up.key, up.upload_id)
                out.aborted_uploads.append(up.key)

    for tenant_root in store.list_prefixes(f"{TENANTS_ROOT}/"):
        tenant = tenant_root.split("/")[1]
        roots = {
            r.rstrip("/").rpartition("/")[2]: r for r in store.list_prefixes(bucket_scenes_of(tenant_root))
        }
        known = scenes.listed_uploads(tenant, sorted(roots))
        for scene_id, root in roots.items():
            if root in finished:
                continue
            has_row = scene_id in known  # a scene with a row is not listed: its tenant's
            objects = (
                [] if has_row else [(o.key, _age_s(o.last_modified, now)) for o in store.list_objects(root)]
            )
            verdict = root_verdict(root, has_row, objects, max_age_s)
            if verdict == Verdict.legacy:
                log.warning("orphan sweep: %s has an earlier release's record and no row; kept "
                            "(run `bfields-service import-scenes`)", root)  # fmt: skip
            if verdict != Verdict.orphan:
                continue
            if scenes.listed_uploads(tenant, [scene_id]):
                continue  # its row was inserted meanwhile (an upload that copied slowly)
            store.delete_prefix(root)
            out.deleted_prefixes.append(root)
    return out
