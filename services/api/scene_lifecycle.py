"""A scene's life: uploading -> ready, or deleted for good; what keeps it so across requests.

Why: `complete` (minutes: assemble, validate, copy into the bucket) and `delete` (mark, then a
listing and a batch delete) run side by side. A delete that answered 204 while a completion was
still copying files once let the completion publish its record afterwards: a deleted scene came
back, sometimes with only part of its files. Rules now (the scene's row, `common.scenes`):

- **The row decides.** `delete` first marks the row ``deleting`` (committed before anything is
  removed), then aborts the scene's multipart uploads, removes its objects and purges the row.
  From the mark on the scene is gone for every route (404), whatever objects are still on their
  way out, and what a delete that stopped half-way leaves, the sweeper removes
  (`sweeper.sweep_bucket`). Ids are never reused, so a purged row never hides a new scene.
- **Row locks order the deciding steps.** `complete` publishes the ready record in one
  transaction holding the row ``FOR UPDATE``; `delete` marks it in one, after checking for active
  jobs; a job submission holds the row ``FOR SHARE`` until its jobs are committed. So a delete
  either comes before the ready record (the completion finds the row deleting or gone, removes
  what it copied and answers 404) or after it (the delete removes the complete scene), and a job
  is either committed before the delete looks for active jobs (409) or refused because the row
  says deleting (404).
- **Completion claim.** One `complete` per scene at a time (409 for a second), so two
  completions never interleave their copies. This one is an advisory session lock, not a row
  lock: it spans minutes of copying, which must not hold a transaction open.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from fastapi import HTTPException, status
from sqlalchemy import Engine

from bayesian_fields_service.records.locks import LockBusy, session_locks


def gone(scene_id: str) -> HTTPException:
    """The answer to a completion whose scene was deleted while it ran."""
    return HTTPException(status.HTTP_404_NOT_FOUND, f"scene {scene_id!r} not found (it was deleted)")


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
