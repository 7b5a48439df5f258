"""A job request checked against its scene, tasks and parameters, before anything is stored.

Why one place: a single submission, a batch item and a batch retry are the same request and must
be refused for the same reasons with the same words. `Validation` caches per request what depends
only on the scene (its record, the parameters checked against it), so a 50,000-item batch over a
few scenes validates once per distinct scene.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from pydantic import ValidationError

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.task_list import normalise_tasks
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.jobs.model import JobRecord
from bayesian_fields_service.jobs.queue import Priority
from bayesian_fields_service.jobs.refusals import Conflict, Invalid, Missing
from bayesian_fields_service.records.ids import BATCH_ID as BATCH_ID  # the routes check batch ids with it
from bayesian_fields_service.records.ids import JOB_ID, SCENE_ID, is_id, new_id
from bayesian_fields_service.scenes.model import SceneRecord
from bayesian_fields_service.scenes.store import SceneStore
from bayesian_fields_service.webhooks.callbacks import check_callback_url

#: Model profiles a job may name. The workers map "default" to BFIELDS_MODEL_PROFILE.
MODEL_PROFILES = ("default",)


@dataclass(frozen=True)
class JobAsk:
    """What a client asks for one job (a submission's body or one batch item)."""

    scene_id: str
    tasks: list[str]
    parameters: dict[str, Any] = field(default_factory=dict)
    model_profile: str = "default"
    priority: Priority = "interactive"
    callback_url: str | None = None
    idempotency_key: str | None = None


def check_id(kind: str, ident: str, prefix: str) -> None:
    """Ids are the service's own (`prefix` + 22 hex digits): anything else cannot exist, so it is
    `Missing` before any lookup (a NUL or a stray byte never reaches the database)."""
    if not is_id(ident, prefix):
        raise Missing(f"{kind} {ident!r} not found")


def checked_callback(settings: ServiceSettings, url: str | None) -> str | None:
    """`url` when a callback may go there (None stays None); `Invalid` naming the rule."""
    if url is None:
        return None
    try:
        return check_callback_url(url, settings)
    except InputError as exc:
        raise Invalid(str(exc)) from None


def check_params_against_scene(params: PipelineParams, summary: dict[str, Any]) -> None:
    """Refuse parameters the scene cannot satisfy now, instead of a job failing later."""
    frames = int(summary.get("frames", 0) or 0)
    depth_frames = int(summary.get("depth_frames", frames) or 0)  # unknown on old scenes: allow
    if params.depth_source == "input" and depth_frames < frames:
        raise Invalid(
            f"parameters.depth_source: 'input' needs a depth map for every frame; the scene has "
            f"{depth_frames} of {frames} (use 'median' or 'expected' to render depth instead)"
        )


def checked_params(parameters: dict[str, Any], scene: SceneRecord) -> dict[str, Any]:
    """The parameters as stored (only those set), validated and checked against the scene."""
    try:
        validated = PipelineParams.model_validate(parameters)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise Invalid(f"parameters.{where}: {first['msg']}") from None
    check_params_against_scene(validated, scene.summary)
    return validated.model_dump(mode="json", exclude_unset=True)


@dataclass
class Validation:
    """Builds checked `JobRecord`s for one request (caches: module docstring)."""

    settings: ServiceSettings
    scenes: SceneStore
    tenant: str
    _scenes: dict[str, SceneRecord] = field(default_factory=dict)
    _params: dict[str, dict[str, Any]] = field(default_factory=dict)

    def scene(self, scene_id: str) -> SceneRecord:
        if scene_id not in self._scenes:
            check_id("scene", scene_id, SCENE_ID)
            record = self.scenes.get(self.tenant, scene_id)
            if record is None:
                raise Missing(f"scene {scene_id!r} not found")
            self._scenes[scene_id] = record
        return self._scenes[scene_id]

    def job(self, ask: JobAsk, *, batch_id: str | None = None) -> JobRecord:
        """A new job record for `ask` (not stored), or the refusal."""
        scene = self.scene(ask.scene_id)
        if scene.state.value != "ready":
            raise Conflict(f"scene {ask.scene_id!r} is not ready (upload not completed)")
        s = self.settings
        try:
            tasks = normalise_tasks(
                ask.tasks, source="tasks", max_tasks=s.max_tasks, max_chars=s.max_task_chars
            )
        except InputError as exc:
            raise Invalid(str(exc)) from None
        if ask.scene_id not in self._params:
            self._params[ask.scene_id] = checked_params(ask.parameters, scene)
        if ask.model_profile not in MODEL_PROFILES:
            raise Invalid(
                f"model_profile {ask.model_profile!r} is unknown; available: {', '.join(MODEL_PROFILES)}"
            )
        return JobRecord(
            id=new_id(JOB_ID), tenant=self.tenant, scene_id=ask.scene_id, tasks=tasks,
            parameters=dict(self._params[ask.scene_id]), model_profile=ask.model_profile, batch_id=batch_id,
            idempotency_key=ask.idempotency_key, priority=ask.priority,
            callback_url=checked_callback(s, ask.callback_url),
        )  # fmt: skip
