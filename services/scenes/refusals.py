"""Why the scenes domain turns a request down, as exceptions the callers map to their answers.

Each kind says what happened to the scene, not which HTTP status it is; the API maps them in one
table (`api.edge`): `SceneGone` 404, `SceneConflict` 409, `UploadTooLarge` 413, `NoDirectUploads`
501. A malformed upload is the library's `InputError` (422), naming the file and the limit.
"""

from __future__ import annotations


class SceneRefused(Exception):
    """A request about a scene the domain will not carry out; `str()` is the user's message."""


class SceneGone(SceneRefused, LookupError):
    """The scene has no row, or its row is being deleted."""

    def __init__(self, scene_id: str, message: str | None = None) -> None:
        super().__init__(message or f"scene {scene_id!r} not found")
        self.scene_id = scene_id


class DeletedMeanwhile(SceneGone):
    """A completion found its scene deleted while it ran (what it copied is removed)."""

    def __init__(self, scene_id: str) -> None:
        super().__init__(scene_id, f"scene {scene_id!r} not found (it was deleted)")


class SceneConflict(SceneRefused):
    """The scene's current state forbids the request."""


class SceneNotReady(SceneConflict):
    """A job was asked for on a scene whose upload is not completed."""

    def __init__(self, scene_id: str) -> None:
        super().__init__(f"scene {scene_id!r} is not ready (upload not completed)")
        self.scene_id = scene_id


class SceneNotUploading(SceneConflict):
    """A completion found the scene already past ``uploading`` (an earlier completion won)."""

    def __init__(self, scene_id: str, state: str) -> None:
        super().__init__(f"scene {scene_id!r} is already {state}")
        self.scene_id = scene_id
        self.state = state


class SceneBusy(SceneConflict):
    """A delete was refused: a job on the scene is queued or running."""

    def __init__(self, scene_id: str, job_id: str, job_state: str) -> None:
        super().__init__(f"scene {scene_id!r} has {job_state} job {job_id}")
        self.scene_id = scene_id
        self.job_id = job_id
        self.job_state = job_state


class CompletionBusy(SceneConflict):
    """Another completion of the scene is running (one at a time: their copies never interleave)."""

    def __init__(self, scene_id: str) -> None:
        super().__init__(f"scene {scene_id!r} is already being completed")
        self.scene_id = scene_id


class UploadVanished(SceneConflict):
    """A file's multipart upload is no longer known to the bucket (aborted or expired)."""

    def __init__(self, name: str) -> None:
        super().__init__(f"the upload of {name!r} no longer exists (aborted or expired)")
        self.name = name


class UploadTooLarge(SceneRefused):
    """The announced files together exceed the upload limit."""

    def __init__(self, total: int, limit: int) -> None:
        super().__init__(f"upload of {total} bytes exceeds the limit of {limit} bytes")
        self.total = total
        self.limit = limit


class NoDirectUploads(SceneRefused):
    """The storage backend cannot presign URLs (a local folder): no presigned upload exists."""

    def __init__(self) -> None:
        super().__init__("the storage backend cannot presign URLs")
