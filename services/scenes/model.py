"""A scene as the API shows it, and a scene whose delete was acknowledged (which it never shows).

Ids are time-ordered (``s_`` + ms timestamp + randomness, `common.jobs.new_id`), so newest first
is descending id order, which is also the listing's cursor.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from enum import StrEnum
from typing import Any

from pydantic import BaseModel, Field

SCENE_EXAMPLE_ID = "s_0192f3a1b2c3aa55bb66cc"
#: The row state of a scene whose delete was acknowledged (never shown by the API: a 404).
DELETING = "deleting"


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


@dataclass(frozen=True)
class DeletingScene:
    """A scene whose delete was acknowledged but whose row is not purged yet: what is left of
    its row (its earlier state is gone with the mark; its pending uploads are still to abort)."""

    tenant: str
    id: str
    pending_uploads: list[dict[str, Any]]


#: A scene's row as the domain reads it: its record, or the remains of one being deleted.
SceneRow = SceneRecord | DeletingScene
