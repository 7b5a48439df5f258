"""The in-process pipeline end to end on a tiny rendered scene with real models.

Covers what the pipeline promises beyond its parts: a readable, consistent result; task-independent
caches reused across task lists (proved by counting calls into the real models); resume after a
crash; cancellation between frames; the ablation switches; determinism.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bayesian_fields_core.errors import CancelledError
from bayesian_fields_core.job.artifacts import ACCEPTED_KEY, FUSION_KEY
from bayesian_fields_core.job.markers import is_done
from bayesian_fields_core.job.pipeline import run_job, run_stage
from bayesian_fields_core.job.stage_table import STAGES
from bayesian_fields_core.job.store import LocalStore, get_arrays
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.results.reader import read_result
from bayesian_fields_core.scene.loader import load_scene
from tests.core.conftest import N_FRAMES, OTHER_TASKS, TASKS, counting_models, make_job

# Slow (the inner loop leaves it out): its fixtures took 5.4 s to set up here (--durations).
pytestmark = pytest.mark.slow


def _result(job_root: Path):
    return read_result(LocalStore(job_root), "job/result/")


@pytest.fixture(scope="module")
def baseline(scene_dir: Path, profile: dict[str, Any], tmp_path_factory: pytest.TempPathFactory) -> dict:
    """One clean run from empty caches; other tests compare against it and reuse its caches."""
    root = tmp_path_factory.mktemp("baseline")
    models = counting_models(profile)
    job = make_job(scene_dir, root / "job", root / "cache", models)
    reports = run_job(job)
    return {
        "root": root,
        "job": job,
        "reports": reports,
        "result": _result(root / "job"),
        "counts": dict(models.counts),
    }


def test_end_to_end_result_is_complete_and_consistent(baseline: dict, scene_dir: Path) -> None:
    result, reports, job = baseline["result"], baseline["reports"], baseline["job"]
    means = load_scene(scene_dir).gaussians.means
    n_objects = result.probabilities.shape[0]

    assert result.tasks == TASKS
    assert list(result.selections) == TASKS
    assert result.object_ids.shape == (len(means),)
    assert n_objects > 0
    assert result.object_ids.min() >= -1 and result.object_ids.max() < n_objects
    assert result.probabilities.shape == (n_objects, len(TASKS) + 1)
    np.testing.assert_allclose(result.probabilities.sum(axis=1), 1.0, atol=1e-5)
    assert all(is_done(job.spec, stage) for stage in STAGES)

    # Every stage did its real work once per frame.
    assert reports["perceive"]["frames_computed"] == N_FRAMES
    assert reports["fuse"]["frames_rendered"] == N_FRAMES
    assert baseline["counts"]["segment"] == N_FRAMES
    # Crops are pooled across frames into batches of crop_batch_size: fewer calls than frames.
    perceive = reports["perceive"]
    batches = -(-perceive["masks_computed"] // PipelineParams().crop_batch_size)
    assert baseline["counts"]["encode_images"] == perceive["encoder_calls"] == batches < N_FRAMES

    selected = [obj for objs in result.selections.values() for obj in objs]
    assert selected, "no task selected any object"
    assert result.relevance is not None and result.relevance.shape == (n_objects, len(TASKS))
    assert (result.relevance >= 0).all() and (result.relevance <= 1).all()
    # Each object's Gaussians before the kNN filter: those of the primitives it is made of.
    prims = result.primitive_ids
    kept = result.object_ids >= 0
    object_of_primitive = np.full(prims.max() + 1, -1)
    object_of_primitive[prims[kept]] = result.object_ids[kept]
    unfiltered = np.where(prims >= 0, object_of_primitive[np.maximum(prims, 0)], -1)
    logodds = get_arrays(job.spec.store, job.spec.key(FUSION_KEY))["logodds"]
    for task, objects in result.selections.items():
        t = TASKS.index(task)
        assert len(objects) <= job.spec.params.top_k
        # Ranked by evidence (mean fused log-odds), reported with their relevance p(y=1|object).
        evidence = [float(logodds[unfiltered == o.object_id, t].mean()) for o in objects]
        assert evidence == sorted(evidence, reverse=True)
        for obj in objects:
            members = means[result.object_ids == obj.object_id].astype(np.float64)
            assert obj.num_gaussians == len(members) > 0
            assert (unfiltered == obj.object_id).sum() >= job.spec.params.min_object_gaussians
            assert obj.probability == pytest.approx(float(result.relevance[obj.object_id, t]), abs=1e-6)
            np.testing.assert_allclose(obj.centroid, members.mean(axis=0), atol=1e-5)
            grown = type(obj.box)(obj.box.center, obj.box.rotation, obj.box.extents + 1e-5)
            assert grown.contains(members).all()


def test_new_task_list_reuses_perception_and_visibility(
    baseline: dict, scene_dir: Path, profile: dict, tmp_path: Path
) -> None:
    models = counting_models(profile)
    job = make_job(scene_dir, tmp_path / "job", baseline["root"] / "cache", models, tasks=OTHER_TASKS)
    reports = run_job(job)

    # reuse is proven by the counts, not by wall time (which the shared machine's load decides)
    assert models.counts["segment"] == 0
    assert models.counts["encode_images"] == 0
    assert models.counts["segmenter_built"] == 0  # a cached scene loads no segmenter at all
    assert models.counts["encode_texts"] == 1  # only the new tasks are encoded
    assert reports["perceive"]["frames_cached"] == N_FRAMES
    assert reports["perceive"]["frames_computed"] == 0
    assert reports["fuse"]["frames_rendered"] == 0
    result = _result(tmp_path / "job")
    assert result.tasks == OTHER_TASKS
    assert list(result.selections) == OTHER_TASKS


class _CrashAfter:
    """A progress callback that raises once `stage` reports `fraction` (a crash mid-stage)."""

    def __init__(self, stage: str, fraction: float) -> None:
        self.stage, self.fraction = stage, fraction

    def __call__(self, stage: str, fraction: float) -> None:
        if stage == self.stage and fraction >= self.fraction - 1e-9:
            raise RuntimeError(f"simulated crash in {stage} at {fraction:.2f}")


def test_resume_after_crash_in_fuse(baseline: dict, scene_dir: Path, profile: dict, tmp_path: Path) -> None:
    crashed_after = 2
    first = make_job(
        scene_dir,
        tmp_path / "job",
        tmp_path / "cache",
        counting_models(profile),
        progress=_CrashAfter("fuse", crashed_after / N_FRAMES),
    )
    with pytest.raises(RuntimeError, match="simulated crash in fuse"):
        run_job(first)
    assert (
        is_done(first.spec, "perceive")
        and not is_done(first.spec, "fuse")
        and not is_done(first.spec, "cluster")
    )
    perceive_marker = run_stage("perceive", first)  # marker read back, nothing recomputed

    models = counting_models(profile)
    resumed = make_job(scene_dir, tmp_path / "job", tmp_path / "cache", models)
    reports = run_job(resumed)
    assert reports["perceive"] == perceive_marker
    assert models.counts["segment"] == 0 and models.counts["encode_images"] == 0
    # Frames whose visibility was cached before the crash are not rendered again.
    assert reports["fuse"]["frames_rendered"] == N_FRAMES - crashed_after

    result, clean = _result(tmp_path / "job"), baseline["result"]
    np.testing.assert_array_equal(result.object_ids, clean.object_ids)
    np.testing.assert_array_equal(result.probabilities, clean.probabilities)
    assert {t: [o.object_id for o in objs] for t, objs in result.selections.items()} == {
        t: [o.object_id for o in objs] for t, objs in clean.selections.items()
    }


class _CancelAfter:
    """should_cancel that turns True on its (n+1)-th call."""

    def __init__(self, n: int) -> None:
        self.n, self.calls = n, 0

    def __call__(self) -> bool:
        self.calls += 1
        return self.calls > self.n


@pytest.mark.parametrize("stage", ["perceive", "fuse"])
def test_cancel_between_frames(stage: str, scene_dir: Path, profile: dict, tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    if stage == "fuse":
        run_stage("perceive", make_job(scene_dir, tmp_path / "job", cache, counting_models(profile)))
    cancel = _CancelAfter(3)
    job = make_job(scene_dir, tmp_path / "job", cache, counting_models(profile), should_cancel=cancel)
    with pytest.raises(CancelledError):
        run_job(job)
    assert cancel.calls == 4  # checked at the stage boundary and before each frame: stopped before the third
    assert not is_done(job.spec, stage)
    assert not is_done(job.spec, "cluster")
    prefix = job.scene.keys.perception_prefix if stage == "perceive" else job.scene.keys.visibility_prefix
    assert len(LocalStore(cache).list(prefix)) == 2  # the two finished frames stay cached

    reports = run_job(make_job(scene_dir, tmp_path / "job", cache, counting_models(profile)))
    if stage == "perceive":
        assert reports["perceive"]["frames_computed"] == N_FRAMES - 2
    else:
        assert reports["fuse"]["frames_rendered"] == N_FRAMES - 2
    assert is_done(job.spec, "cluster")


def _variant(
    baseline: dict, scene_dir: Path, profile: dict, job_root: Path, **params: Any
) -> tuple[dict, Any]:
    """Run with changed parameters on the baseline's caches (so only fuse and cluster compute)."""
    job = make_job(
        scene_dir,
        job_root,
        baseline["root"] / "cache",
        counting_models(profile),
        params=PipelineParams(**params),
    )
    return run_job(job), job


def test_ablation_no_outlier_rejection_accepts_every_mask(
    baseline: dict, scene_dir: Path, profile: dict, tmp_path: Path
) -> None:
    assert baseline["reports"]["fuse"]["masks_rejected"] > 0  # the switch has something to change
    reports, job = _variant(baseline, scene_dir, profile, tmp_path / "job", outlier_rejection=False)
    assert reports["fuse"]["masks_rejected"] == 0
    assert reports["fuse"]["masks"] == baseline["reports"]["fuse"]["masks"]
    assert get_arrays(job.spec.store, job.spec.key(ACCEPTED_KEY))["accepted"].all()
    assert (
        reports["cluster"]["counts"]["primitives"] >= baseline["reports"]["cluster"]["counts"]["primitives"]
    )


def test_ablation_average_fusion_runs_and_differs(
    baseline: dict, scene_dir: Path, profile: dict, tmp_path: Path
) -> None:
    reports, job = _variant(baseline, scene_dir, profile, tmp_path / "job", fusion="average")
    fused = get_arrays(job.spec.store, job.spec.key(FUSION_KEY))
    bayes = get_arrays(baseline["job"].spec.store, baseline["job"].spec.key(FUSION_KEY))
    assert "observed" in fused and fused["observed"].any()
    assert fused["probabilities"].shape == bayes["probabilities"].shape
    assert not np.allclose(fused["probabilities"], bayes["probabilities"])
    result = _result(tmp_path / "job")
    assert result.parameters["fusion"] == "average"
    np.testing.assert_allclose(result.probabilities.sum(axis=1), 1.0, atol=1e-5)


def test_ablation_without_knn_filter_removes_nothing(
    baseline: dict, scene_dir: Path, profile: dict, tmp_path: Path
) -> None:
    removed = baseline["reports"]["cluster"]["counts"]["knn_removed_gaussians"]
    assert removed > 0  # the filter does remove floaters in the default run
    reports, _ = _variant(baseline, scene_dir, profile, tmp_path / "job", knn_filter=False)
    assert reports["cluster"]["counts"]["knn_removed_gaussians"] == 0
    unfiltered, filtered = _result(tmp_path / "job").object_ids, baseline["result"].object_ids
    changed = unfiltered != filtered
    # The only difference is the floaters the filter took out of selected objects.
    assert changed.sum() == removed
    assert (filtered[changed] == -1).all() and (unfiltered[changed] >= 0).all()


def test_two_clean_runs_are_identical(baseline: dict, scene_dir: Path, profile: dict, tmp_path: Path) -> None:
    run_job(make_job(scene_dir, tmp_path / "job", tmp_path / "cache", counting_models(profile)))
    again, first = _result(tmp_path / "job"), baseline["result"]
    np.testing.assert_array_equal(again.object_ids, first.object_ids)
    np.testing.assert_array_equal(again.primitive_ids, first.primitive_ids)
    np.testing.assert_array_equal(again.probabilities, first.probabilities)
    for task in TASKS:
        assert [(o.object_id, o.num_gaussians) for o in again.selections[task]] == [
            (o.object_id, o.num_gaussians) for o in first.selections[task]
        ]


def test_scene_where_every_mask_is_rejected_gives_an_empty_result(
    baseline: dict, scene_dir: Path, profile: dict, tmp_path: Path
) -> None:
    """Tasks nothing in the scene matches: OR-phi rejects every mask, the job still succeeds."""
    hopeless = dict(profile, calibration={"mu0": 0.9, "mu1": 1.0, "s": 0.05})
    job = make_job(scene_dir, tmp_path / "job", baseline["root"] / "cache", counting_models(hopeless))
    reports = run_job(job)
    assert reports["fuse"]["masks_rejected"] == reports["fuse"]["masks"] > 0
    assert reports["cluster"]["counts"]["primitives"] == 0
    result = _result(tmp_path / "job")
    assert result.probabilities.shape == (0, len(TASKS) + 1)
    assert (result.object_ids == -1).all()
    assert all(len(result.selections[task]) == 0 for task in TASKS)
