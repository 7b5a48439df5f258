"""The fuse stage's torch path (what a CUDA worker runs) against its numpy path, on the CPU.

`fusion_backend='torch'` renders depth into tensors and runs projection, depth test and the
log-odds update as torch ops on the render device; on `cpu` that is the very code a GPU worker
runs on `cuda`. Both stages must write the same associations, acceptance flags and
probabilities.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.special import logit

from bayesian_fields_core.job.artifacts import ACCEPTED_KEY, FUSION_KEY
from bayesian_fields_core.job.pipeline import run_stage
from bayesian_fields_core.job.store import LocalStore, get_arrays
from bayesian_fields_core.params import PipelineParams

from .conftest import counting_models, make_ctx


@pytest.mark.parametrize("depth_source", ["median", "expected"])
def test_torch_fusion_equals_numpy_fusion(
    depth_source: str, scene_dir: Path, profile: dict[str, Any], tmp_path: Path
) -> None:
    cache_np, cache_t = tmp_path / "cache-np", tmp_path / "cache-t"
    params = {"depth_source": depth_source}
    first = make_ctx(
        scene_dir,
        tmp_path / "job-np",
        cache_np,
        counting_models(profile),
        params=PipelineParams(**params, fusion_backend="numpy"),
    )
    run_stage("perceive", first)
    shutil.copytree(cache_np, cache_t)  # the same perception for both: only fusion differs
    marker_np = run_stage("fuse", first)
    second = make_ctx(
        scene_dir,
        tmp_path / "job-t",
        cache_t,
        counting_models(profile),
        params=PipelineParams(**params, fusion_backend="torch"),
    )
    marker_t = run_stage("fuse", second)
    assert marker_np["fusion_backend"] == "numpy" and marker_t["fusion_backend"] == "torch"
    assert marker_t["frames_rendered"] == marker_np["frames_rendered"] > 0

    vis = sorted(p for p in cache_np.rglob("*.npz") if "visibility" in p.relative_to(cache_np).parts)
    assert vis
    for path in vis:
        a = np.load(path, allow_pickle=False)
        b = np.load(cache_t / path.relative_to(cache_np), allow_pickle=False)
        np.testing.assert_array_equal(a["gaussian_ids"], b["gaussian_ids"])
        np.testing.assert_array_equal(a["mask_ids"], b["mask_ids"])
    fused_np = get_arrays(LocalStore(tmp_path / "job-np"), "job/" + FUSION_KEY)
    fused_t = get_arrays(LocalStore(tmp_path / "job-t"), "job/" + FUSION_KEY)
    assert (fused_np["logodds"] != fused_np["logodds"][0, 0]).any()  # evidence was fused
    np.testing.assert_allclose(fused_t["logodds"], fused_np["logodds"], rtol=0, atol=1e-4)
    np.testing.assert_allclose(fused_t["probabilities"], fused_np["probabilities"], rtol=0, atol=1e-6)
    acc_np = get_arrays(LocalStore(tmp_path / "job-np"), "job/" + ACCEPTED_KEY)
    acc_t = get_arrays(LocalStore(tmp_path / "job-t"), "job/" + ACCEPTED_KEY)
    np.testing.assert_array_equal(acc_t["accepted"], acc_np["accepted"])


def test_auto_backend_is_numpy_on_cpu(scene_dir: Path, profile: dict[str, Any], tmp_path: Path) -> None:
    from bayesian_fields_core.stages.fuse import fusion_on_torch

    ctx = make_ctx(scene_dir, tmp_path / "job", tmp_path / "cache", counting_models(profile))
    assert ctx.params.fusion_backend == "auto"
    assert not fusion_on_torch(ctx, "cpu")
    assert fusion_on_torch(ctx, "cuda")  # the decision only; no CUDA is touched
    avg = make_ctx(
        scene_dir,
        tmp_path / "job2",
        tmp_path / "cache",
        counting_models(profile),
        params=PipelineParams(fusion="average", fusion_backend="torch"),
    )
    assert not fusion_on_torch(avg, "cuda")  # the averaging ablation stays on numpy


def test_view_correlation_shrinks_evidence_alike_on_both_backends(
    scene_dir: Path, profile: dict[str, Any], tmp_path: Path
) -> None:
    """The stage counts each Gaussian's accepted views on either backend and divides its evidence
    by 1 + (n - 1) rho: never more evidence than the paper's update, less for Gaussians seen twice+."""
    cache = tmp_path / "cache"
    logodds: dict[str, np.ndarray] = {}
    for name, params in {
        "paper": PipelineParams(fusion_backend="numpy"),
        "numpy": PipelineParams(fusion_backend="numpy", view_correlation=0.3),
        "torch": PipelineParams(fusion_backend="torch", view_correlation=0.3),
    }.items():
        ctx = make_ctx(scene_dir, tmp_path / name, cache, counting_models(profile), params=params)
        if name == "paper":
            run_stage("perceive", ctx)
        run_stage("fuse", ctx)
        logodds[name] = get_arrays(LocalStore(tmp_path / name), "job/" + FUSION_KEY)["logodds"]
    base = np.float32(logit(PipelineParams().prior))  # where every Gaussian's evidence starts
    paper, discounted = logodds["paper"] - base, logodds["numpy"] - base
    np.testing.assert_allclose(logodds["torch"], logodds["numpy"], rtol=0, atol=1e-4)
    assert np.all(np.abs(discounted) <= np.abs(paper) + 1e-4)
    assert (np.abs(discounted) < 0.5 * np.abs(paper)).any()
