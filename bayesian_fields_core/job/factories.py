"""A job for each place one runs: a local folder (`local_job`) or a store (`store_job`).

Every program that runs the pipeline builds its jobs here (the CLI, the workers, the evaluation,
calibration, the benches, the tests), so a job is assembled one way: its `JobSpec` (what it is),
its `JobScene` (what it runs on) and its `Runner` (what runs it), bundled as a `Job`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypedDict, Unpack

from bayesian_fields_core.job.flight import Flight, NoFlight
from bayesian_fields_core.job.job_scene import JobScene
from bayesian_fields_core.job.runner import CancelFn, ProgressFn, Runner, never_cancel, no_progress
from bayesian_fields_core.job.scene_source import LocalFolder, SceneSource, StoreDownload
from bayesian_fields_core.job.spec import JobSpec, as_prefix
from bayesian_fields_core.job.store import LocalStore, Store
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import Models


@dataclass(frozen=True)
class Job:
    """A job's three parts, as `pipeline.run_job` / `run_stage` take them."""

    spec: JobSpec
    scene: JobScene
    runner: Runner


class LocalJobOptions(TypedDict, total=False):
    """What `local_job` lets a caller choose beyond the folders (all optional)."""

    job_prefix: str
    """Where in `out` the job's artifacts go (default ``""``: `out` is the job)."""
    cache_prefix: str
    """Where in `cache_dir` the caches go (default ``""``: one cache for every scene)."""
    allow_source_path: bool
    splat_transform: Path | None
    progress: ProgressFn
    should_cancel: CancelFn


def _assemble(
    spec: JobSpec,
    source: SceneSource,
    runner: Runner,
    *,
    allow_source_path: bool = False,
    splat_transform: Path | None = None,
) -> Job:
    scene = JobScene(
        spec,
        source,
        models_fingerprint=runner.models.fingerprint,
        profile_name=runner.models.profile_name,
        allow_source_path=allow_source_path,
        splat_transform=splat_transform,
    )
    return Job(spec, scene, runner)


def local_job(
    scene_dir: Path,
    out: Path,
    cache_dir: Path,
    tasks: Sequence[str],
    params: PipelineParams,
    models: Models,
    **options: Unpack[LocalJobOptions],
) -> Job:
    """A job on local folders (`bfields run`, the evaluation, calibration, benches, tests): the
    scene read from `scene_dir`, the job written to `out`, the caches kept in `cache_dir`.

    Cache keys are content digests, so one cache serves every scene wherever its folder is; the
    scene's own path reaches only the cache index (for `bfields cache ls`) and the result's
    provenance (for `bfields view`).
    """
    spec = JobSpec(
        store=LocalStore(out),
        job_prefix=options.get("job_prefix", ""),
        tasks=tuple(tasks),
        params=params,
        cache_store=LocalStore(cache_dir),
        cache_prefix=options.get("cache_prefix", ""),
    )
    runner = Runner(
        models,
        progress=options.get("progress", no_progress),
        should_cancel=options.get("should_cancel", never_cancel),
    )
    return _assemble(
        spec,
        LocalFolder(scene_dir),
        runner,
        allow_source_path=options.get("allow_source_path", False),
        splat_transform=options.get("splat_transform"),
    )


def store_job(
    store: Store,
    job_prefix: str,
    scene_prefix: str,
    tasks: Sequence[str],
    params: PipelineParams,
    models: Models,
    *,
    scene_source: SceneSource | None = None,
    work_dir: Path | None = None,
    progress: ProgressFn = no_progress,
    should_cancel: CancelFn = never_cancel,
    flight: Flight | None = None,
) -> Job:
    """A job whose scene and caches live in a store (a worker's tenant bucket): the scene's files
    under ``<scene_prefix>input/``, its caches under ``<scene_prefix>cache/``, the job's artifacts
    under `job_prefix`. The scene folder comes from `scene_source` (the worker's shared scene
    copy), else it is downloaded into `work_dir` (`StoreDownload`). `flight` shares the filling
    of the scene's caches with concurrent jobs (a worker's `RedisFlight`; default `NoFlight`). A
    service job never follows a ``source_path`` outside its upload."""
    scene_prefix = as_prefix(scene_prefix)
    spec = JobSpec(
        store=store,
        job_prefix=job_prefix,
        tasks=tuple(tasks),
        params=params,
        cache_store=store,
        cache_prefix=scene_prefix + "cache/",
    )
    source = scene_source if scene_source is not None else StoreDownload(store, scene_prefix, work_dir)
    runner = Runner(models, progress, should_cancel, NoFlight() if flight is None else flight)
    return _assemble(spec, source, runner)
