"""The perceive stage with prefetch threads and cross-frame crop batches gives the same cache."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bayesian_fields_core.job.pipeline import run_stage
from bayesian_fields_core.params import PipelineParams
from tests.core.conftest import N_FRAMES, counting_models, make_job


@pytest.mark.slow
def test_batched_prefetched_perception_equals_sequential(
    scene_dir: Path, profile: dict[str, Any], tmp_path: Path
) -> None:
    seq_models = counting_models(profile)
    seq = make_job(
        scene_dir,
        tmp_path / "a",
        tmp_path / "cache-a",
        seq_models,
        params=PipelineParams(prefetch_frames=0, crop_batch_size=4096),
    )
    marker_seq = run_stage("perceive", seq)
    par_models = counting_models(profile)
    par = make_job(
        scene_dir,
        tmp_path / "b",
        tmp_path / "cache-b",
        par_models,
        params=PipelineParams(prefetch_frames=2, crop_batch_size=7),
    )
    marker_par = run_stage("perceive", par)

    masks = marker_seq["masks_computed"]
    assert masks == marker_par["masks_computed"] > 7 * N_FRAMES // 2
    assert marker_seq["encoder_calls"] == 1  # everything pooled into one batch
    assert marker_par["encoder_calls"] == -(-masks // 7)  # batches cross frame boundaries
    assert par_models.counts["encode_images"] == marker_par["encoder_calls"]
    assert par_models.counts["segment"] == N_FRAMES
    cache_a = tmp_path / "cache-a"
    files = sorted(p for p in cache_a.rglob("*.npz") if "perception" in p.relative_to(cache_a).parts)
    assert len(files) == N_FRAMES
    for path in files:
        a = np.load(path, allow_pickle=False)
        b = np.load(tmp_path / "cache-b" / path.relative_to(tmp_path / "cache-a"), allow_pickle=False)
        np.testing.assert_array_equal(a["labels"], b["labels"])
        np.testing.assert_allclose(a["embeddings"], b["embeddings"], atol=1e-5)
    # A second run finds every frame cached and loads no model.
    again_models = counting_models(profile)
    again = make_job(
        scene_dir,
        tmp_path / "c",
        tmp_path / "cache-b",
        again_models,
        params=PipelineParams(crop_batch_size=7),
    )
    assert run_stage("perceive", again)["frames_cached"] == N_FRAMES
    assert again_models.counts["segmenter_built"] == 0 and again_models.counts["encoder_built"] == 0
