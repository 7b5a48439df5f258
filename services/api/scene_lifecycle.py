"""A scene's life: uploading -> ready, or deleted for good; the lock and tombstone that keep it so.

Why: `complete` (minutes: assemble, validate, copy into the bucket) and `delete` (a listing and
a batch delete) used to run side by side. A delete that answered 204 while a completion was still
copying files let the completion publish ``scene.json`` afterwards: a deleted scene came back,
sometimes with only part of its files, and with a record the orphan sweeper honours. Rules now:

- **Tombstone.** `delete` first writes ``tombstones/scenes/<id>`` (tenant store, in the bucket,
  so it outlives a Redis wipe), then removes the scene's objects. A tombstoned scene is gone for
  every route (404), whatever objects are still on their way out, and the sweeper removes what
  is left of it (`sweeper.sweep_bucket`). Ids are never reused, so a tombstone never hides a
  new scene; tombstones are empty objects and are kept.
- **Scene lock.** The steps that decide a scene's fate run under one lock per scene, a
  PostgreSQL session lock (`records.locks`: released with the session, untouched by a Redis loss):
  `delete` checks for active jobs and writes the tombstone; `complete` checks the tombstone and
  writes the ready record; a job submission checks the scene and stores the job. So a delete
  either comes before the ready record (the completion sees the tombstone, removes what it copied
  and answers 404) or after it (the delete removes the complete scene), and a job is either stored
  before the delete looks for active jobs (409) or refused because the scene is gone (404).
- **Completion claim.** One `complete` per scene at a time (409 for a second), so two
  completions never interleave their copies.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator

from fastapi import HTTPException, status
from sqlalchemy import Engine

from bayesian_fields_core.job.store import Store
from bayesian_fields_service.records.locks import LockBusy, lock_key, session_locks

#: Scene locks per tenant: a scene takes the slot its id hashes to, so a batch over thousands of
#: scenes holds at most this many advisory locks (PostgreSQL's lock table is shared and bounded);
#: two scenes in one slot only wait for each other's short critical sections.
SCENE_LOCK_SLOTS = 256
#: Longest a request waits for another's critical section on the same scene before a 503.
LOCK_WAIT_S = 30.0


def tombstone_key(scene_id: str) -> str:
    """Where `delete` marks a scene as gone (outside ``scenes/<id>/``, which it removes)."""
    return f"tombstones/scenes/{scene_id}"


def is_deleted(ts: Store, scene_id: str) -> bool:
    return ts.exists(tombstone_key(scene_id))


def mark_deleted(ts: Store, scene_id: str) -> None:
    ts.put_bytes(tombstone_key(scene_id), b"")


def gone(scene_id: str) -> HTTPException:
    return HTTPException(status.HTTP_404_NOT_FOUND, f"scene {scene_id!r} not found (it was deleted)")


@contextlib.contextmanager
def scene_lock(database: Engine, tenant: str, scene_ids: Iterable[str]) -> Iterator[None]:
    """Hold the lock of every scene in `scene_ids` (one database session; `records.locks` takes
    them in key order, so two batches naming the same scenes never deadlock). 503 when another
    request holds one for longer than `LOCK_WAIT_S`."""
    slots = {("scene", tenant, str(lock_key(s) % SCENE_LOCK_SLOTS)) for s in scene_ids}
    try:
        with session_locks(database, sorted(slots), wait_s=LOCK_WAIT_S):
            yield
    except LockBusy:
        raise HTTPException(
            status.HTTP_503_SERVICE_UNAVAILABLE,
            "a scene of this request is busy with another change; retry",
            headers={"Retry-After": "2"},
        ) from None


@contextlib.contextmanager
def completion_claim(database: Engine, tenant: str, scene_id: str) -> Iterator[None]:
    """Let one `complete` of the scene run at a time (409 for another meanwhile): a database
    session lock, so an API process that dies mid-completion gives the claim up with its session."""
    try:
        with session_locks(database, [("scene-completion", tenant, scene_id)], wait_s=None):
            yield
    except LockBusy:
        raise HTTPException(
            status.HTTP_409_CONFLICT, f"scene {scene_id!r} is already being completed"
        ) from None
