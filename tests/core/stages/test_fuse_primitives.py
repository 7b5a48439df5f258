"""`fuse` stores the primitives (METHOD step 6) it builds while each frame's associations are in
memory; `cluster` reads them instead of replaying every frame's cached associations. The stored
ids must be exactly the replay's, with either fusion rule."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bayesian_fields_core.job.artifacts import ACCEPTED_KEY, FUSION_KEY, PRIMITIVES_KEY
from bayesian_fields_core.job.pipeline import run_stage
from bayesian_fields_core.job.store import get_arrays
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.stages.cluster import build_primitives, load_primitives, view_counts
from tests.core.conftest import counting_models, make_job


def _job(scene_dir: Path, profile: dict[str, Any], tmp_path: Path, params: PipelineParams) -> Any:
    return make_job(scene_dir, tmp_path / "job", tmp_path / "cache", counting_models(profile), params=params)


def _fused_job(scene_dir: Path, profile: dict[str, Any], tmp_path: Path, params: PipelineParams) -> Any:
    """A job with `params` whose perceive and fuse stages have run."""
    job = _job(scene_dir, profile, tmp_path, params)
    run_stage("perceive", job)
    run_stage("fuse", job)
    return job


@pytest.mark.parametrize("fusion", ["bayes", "average"])
@pytest.mark.slow
def test_fuse_stores_the_primitives_that_replaying_the_frames_gives(
    fusion: str, scene_dir: Path, profile: dict[str, Any], tmp_path: Path
) -> None:
    job = _fused_job(scene_dir, profile, tmp_path, PipelineParams(fusion=fusion))
    stored = get_arrays(job.spec.store, job.spec.key(PRIMITIVES_KEY))["primitive_ids"]
    replayed = build_primitives(job.spec, job.scene, job.runner)
    assert len(np.unique(replayed[replayed >= 0])) > 1
    np.testing.assert_array_equal(stored, replayed)
    np.testing.assert_array_equal(load_primitives(job.spec, job.scene, job.runner), replayed)
    job.spec.store.delete(job.spec.key(PRIMITIVES_KEY))  # a job fused before fuse stored them
    np.testing.assert_array_equal(load_primitives(job.spec, job.scene, job.runner), replayed)


@pytest.mark.slow
def test_fuse_stores_the_view_counts_that_replaying_the_frames_gives(
    scene_dir: Path, profile: dict[str, Any], tmp_path: Path
) -> None:
    """The per-view conditionals (`aib_conditionals='per_view'`) divide by each Gaussian's accepted
    views: `fuse` stores them, and a job fused before it did gets the very same counts again from
    the accepted masks, so the map does not depend on when the job was fused."""
    job = _fused_job(scene_dir, profile, tmp_path, PipelineParams(aib_conditionals="per_view"))
    fused = get_arrays(job.spec.store, job.spec.key(FUSION_KEY))
    stored = fused["view_counts"]
    assert stored.shape == (len(job.scene.loaded.gaussians),) and stored.max() > 1
    older = {k: v for k, v in fused.items() if k != "view_counts"}
    np.testing.assert_array_equal(view_counts(job.spec, job.scene, job.runner, older), stored)
    # an unseen Gaussian has no accepted view; a seen one at most one per fused frame
    frames = len(get_arrays(job.spec.store, job.spec.key(ACCEPTED_KEY))["frame_indices"])
    assert stored.min() == 0 and stored.max() <= frames
    fused_job = _job(scene_dir, profile, tmp_path, PipelineParams(aib_conditionals="fused"))
    assert (
        view_counts(fused_job.spec, fused_job.scene, fused_job.runner, fused) is None
    )  # the paper's conditionals read no counts
