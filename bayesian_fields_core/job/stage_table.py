"""The stage table: every fact about a stage, written once.

The pipeline runs the stages in table order; the worker makes one Celery task per row, named
and routed from it; job progress and the CLI's bars weigh and label stages from it; and the
content keys of the per-frame caches (`cache_keys`) take their parameters from it (which
parameters: the `ReadBy` marker each field of `PipelineParams` carries). Adding a
stage is adding a row here and its module under `stages/`.

A row names its function by import path (``module:function``) and the runtime imports it on
first use. That keeps the job runtime below the stages it runs: stages import the runtime's
`JobSpec`, `JobScene`, `Runner` and store, and nothing in `job/` imports a stage
(`tests/test_layers.py`).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.artifacts import ALIGNMENT_CACHE_DIR, PERCEPTION_CACHE_DIR, VISIBILITY_CACHE_DIR
from bayesian_fields_core.params import PipelineParams, keyed_parameters

StageFunction = Callable[..., dict[str, Any]]
"""`run(spec: JobSpec, scene: JobScene, runner: Runner) -> report`; the parts are not named here,
since `JobScene` imports the table (through its cache keys)."""
Queue = Literal["gpu", "cpu"]


@dataclass(frozen=True)
class CacheSpec:
    """A stage's task-independent per-frame cache and what its content key is made of.

    folder: where under the cache root its entries live (``perception/``, ``visibility/``).
    params: the `PipelineParams` fields whose values enter the key: a change to any of them
        must miss the cache, and a field that is not here must not change what is cached.
        Never written here: it is `params.keyed_parameters(<cache>)`, the fields whose `ReadBy`
        marker names this cache in its `keys`, so a parameter declares it beside its default.
    inputs: the other contents the key hashes, in words (images, cameras, splat, models).
    """

    folder: str
    params: tuple[str, ...]
    inputs: tuple[str, ...]


@dataclass(frozen=True)
class StageSpec:
    """One stage: name, function, worker queue, progress weight and its cache (if any)."""

    name: str
    function: str
    """``module:function`` of `run(spec, scene, runner) -> report`, imported when the stage
    first runs."""
    queue: Queue
    """The worker pool role: "gpu" (segmentation, CLIP, rendering) or "cpu"."""
    weight: float
    """Share of a job's progress bar; the weights of the table add up to 1."""
    cache: CacheSpec | None = None

    @property
    def task_name(self) -> str:
        """The Celery task name of this stage (what the API enqueues by name)."""
        return f"bfields.stage.{self.name}"

    def load(self) -> StageFunction:
        module, _, attribute = self.function.partition(":")
        return getattr(importlib.import_module(module), attribute)


PERCEPTION_CACHE = CacheSpec(
    folder=PERCEPTION_CACHE_DIR,
    params=keyed_parameters("perception"),
    inputs=("image bytes", "image size", "K and distortion when the loader undistorts", "model fingerprint"),
)
VISIBILITY_CACHE = CacheSpec(
    folder=VISIBILITY_CACHE_DIR,
    params=keyed_parameters("visibility"),
    inputs=(
        "perception key of the frame",
        "the scene scale the lengths are fractions of (it depends on every frame, not only this one)",
        "splat digest (means, scales, rotations, opacities)",
        "camera K, pose and size",
        "input depth file and scale when depth_source is 'input'",
    ),
)

ALIGNMENT_CACHE = CacheSpec(
    folder=ALIGNMENT_CACHE_DIR,
    params=keyed_parameters("alignment"),
    inputs=(
        "splat digest and SH colours (the rendered part draws them)",
        "every camera's name, K, distortion, pose and size",
        "image content of the frames the rendered part compares",
        "the source of the check and of what it calls (renderer, image loader, scene scale)",
    ),
)
"""The alignment check's verdict: not a stage's own cache, but run before `perceive` on every job
(`job/alignment_cache.py`). `scene_scale` is here because the check renders with the run's near
plane, a fraction of the scene scale (`alignment_render._near_plane`)."""

STAGE_TABLE: tuple[StageSpec, ...] = (
    StageSpec("perceive", "bayesian_fields_core.stages.perceive:run", "gpu", 0.6, PERCEPTION_CACHE),
    StageSpec("fuse", "bayesian_fields_core.stages.fuse:run", "gpu", 0.25, VISIBILITY_CACHE),
    StageSpec("cluster", "bayesian_fields_core.stages.cluster:run", "cpu", 0.15),
)

STAGES: tuple[str, ...] = tuple(spec.name for spec in STAGE_TABLE)
"""Stage names in the order they run."""

CACHES: tuple[CacheSpec, ...] = (
    *(spec.cache for spec in STAGE_TABLE if spec.cache is not None),
    ALIGNMENT_CACHE,
)
"""Every content-keyed cache: the stages' and the alignment check's."""


def stage(name: str) -> StageSpec:
    """The table row of stage `name` (InputError naming the known stages otherwise)."""
    for spec in STAGE_TABLE:
        if spec.name == name:
            return spec
    raise InputError(f"unknown stage {name!r}; stages are {', '.join(STAGES)}", source="stage")


def cache_parameters(spec: CacheSpec, params: PipelineParams) -> dict[str, Any]:
    """The values of `spec.params` in `params`: what a cache key hashes of the parameters."""
    return {name: getattr(params, name) for name in spec.params}
