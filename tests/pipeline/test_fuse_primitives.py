"""`fuse` stores the primitives (METHOD step 6) it builds while each frame's associations are in
memory; `cluster` reads them instead of replaying every frame's cached associations. The stored
ids must be exactly the replay's, with either fusion rule."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bayesian_fields_core.job.artifacts import PRIMITIVES_KEY
from bayesian_fields_core.job.pipeline import run_stage
from bayesian_fields_core.job.store import get_arrays
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.stages.cluster import build_primitives, load_primitives

from .conftest import counting_models, make_ctx


@pytest.mark.parametrize("fusion", ["bayes", "average"])
def test_fuse_stores_the_primitives_that_replaying_the_frames_gives(
    fusion: str, scene_dir: Path, profile: dict[str, Any], tmp_path: Path
) -> None:
    ctx = make_ctx(
        scene_dir,
        tmp_path / "job",
        tmp_path / "cache",
        counting_models(profile),
        params=PipelineParams(fusion=fusion),
    )
    run_stage("perceive", ctx)
    run_stage("fuse", ctx)
    stored = get_arrays(ctx.store, ctx.job_key(PRIMITIVES_KEY))["primitive_ids"]
    replayed = build_primitives(ctx)
    assert len(np.unique(replayed[replayed >= 0])) > 1
    np.testing.assert_array_equal(stored, replayed)
    np.testing.assert_array_equal(load_primitives(ctx), replayed)
    ctx.store.delete(ctx.job_key(PRIMITIVES_KEY))  # a job fused before fuse stored them
    np.testing.assert_array_equal(load_primitives(ctx), replayed)
