"""What the scenes domain needs from the records: the port its rules are written against.

Why a port: the rules (publish only an uploading scene, refuse a delete while a job is active, a
deleting row reads as absent) are the domain's; the statements are `records.scenes`'. The
service binds the port to PostgreSQL (`postgres.PostgresSceneRecords`), whose row locks order
racing requests; the domain tests bind it to an in-memory fake (tests/services/scenes/fakes.py)
and run without a server.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import AbstractContextManager
from typing import Any, Protocol

from bayesian_fields_service.scenes.model import DeletingScene, SceneRecord, SceneRow


class SceneRows(Protocol):
    """The scene rows inside one unit of work (a transaction, or a read)."""

    def insert(self, record: SceneRecord) -> None:
        """A new scene's row (its id is new: a clash is an error)."""

    def adopt(self, record: SceneRecord, *, deleting: bool) -> bool:
        """The row unless one with its id exists (`deleting`: marked so); True when inserted."""

    def load(self, tenant: str, scene_id: str, *, lock: bool = False) -> SceneRow | None:
        """The scene's row in any state, or None; `lock`: held for update until the unit ends."""

    def share_lock(self, tenant: str, scene_ids: Sequence[str]) -> dict[str, SceneRow]:
        """The rows of `scene_ids` that exist, held shared until the unit of work ends."""

    def page(self, tenant: str, limit: int, before: str | None) -> list[SceneRecord]:
        """Up to `limit` rows not being deleted, descending id, ids below `before` when given."""

    def set_ready(
        self, tenant: str, scene_id: str, *, files: int, size: int, summary: dict[str, Any]
    ) -> SceneRecord:
        """Turn the row ready with its files, bytes and summary, no pending uploads; the new record."""

    def set_deleting(self, tenant: str, scene_id: str) -> None:
        """Mark the row deleting."""

    def purge(self, tenant: str, scene_id: str) -> None:
        """Drop the row if it is deleting (a row in any other state stays)."""

    def deleting(self) -> list[DeletingScene]:
        """Every deleting row of every tenant, by id."""

    def pending_uploads(self, tenant: str, scene_ids: Sequence[str]) -> dict[str, list[dict[str, Any]]]:
        """The pending uploads each row among `scene_ids` lists (any state; absent: no row)."""

    def active_job(self, tenant: str, scene_id: str) -> tuple[str, str] | None:
        """(id, state) of a job on the scene that is queued or running, else None."""

    def drop_answers(self, tenant: str, scene_id: str) -> None:
        """Remove the answers of the scene's jobs (they go with the scene, at once)."""


class SceneRecords(Protocol):
    """Units of work over the scene rows, and the completion claim."""

    def transaction(self) -> AbstractContextManager[SceneRows]:
        """A transaction: committed when the block ends, rolled back when it raises."""

    def read(self) -> AbstractContextManager[SceneRows]:
        """A read outside any transaction the caller holds."""

    def completion_claim(self, tenant: str, scene_id: str) -> AbstractContextManager[None]:
        """Held while one completion of the scene runs; `refusals.CompletionBusy` while another
        holds it. Not a transaction: a completion copies for minutes."""
