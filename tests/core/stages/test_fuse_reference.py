"""The fuse stage against an independent replay of its inputs, on the CPU.

The stage runs the one fusion implementation that a GPU worker runs on `cuda`; here it runs on
the CPU. The replay reads what the stage read (the perception cache, the rendered median depth)
and recomputes every output with numpy: the associations by the homogeneous projection of
tests/core/fusion/reference.py, OR-phi by its definition, the log-odds as a dense float32 sum (one add
per element and frame, as the stage does: equal bit for bit), the best-view margins as a dense
maximum, and the correlated-views discount by its closed form.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from scipy.special import expit, logit

from bayesian_fields_core.fusion.likelihood import log_likelihood_ratio
from bayesian_fields_core.fusion.peak import UNSEEN, margin
from bayesian_fields_core.job.artifacts import ACCEPTED_KEY, FUSION_KEY
from bayesian_fields_core.job.pipeline import run_stage
from bayesian_fields_core.job.store import get_arrays
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.render import GaussianRenderer
from bayesian_fields_core.stages.fuse import fusion_device, likelihood_params
from tests.core.conftest import counting_models, make_job
from tests.core.fusion.reference import reference_associations

# Slow (the inner loop leaves it out): its fixtures took 4.5 s to set up here (--durations).
pytestmark = pytest.mark.slow


def _replay(job: Any) -> dict[str, np.ndarray]:
    """The fused state recomputed from the stage's inputs, frame by frame, in dense numpy."""
    scene = job.scene.loaded
    means = scene.gaussians.means
    n, t = len(means), len(job.spec.tasks)
    text = job.runner.models.encoder.encode_texts(list(job.spec.tasks)).astype(np.float32)
    lik = likelihood_params(job.spec.params, job.runner.models)
    lengths = job.scene.lengths  # the run's lengths in scene units (scene scale x fractions)
    renderer = GaussianRenderer(scene.gaussians, near_plane=lengths.render_near)
    logodds = np.full((n, t), np.float32(logit(job.spec.params.prior)), dtype=np.float32)
    peak = np.full((n, t), UNSEEN, dtype=np.float32)
    views = np.zeros(n, dtype=np.int64)
    accepted_all = []
    for index, frame in job.scene.selected_frames:
        perception = get_arrays(job.spec.cache_store, job.scene.keys.perception_key(index))
        labels = perception["labels"].astype(np.int32)
        phi = perception["embeddings"].astype(np.float32) @ text.T
        depth = renderer.render(frame.K, frame.world_to_camera, frame.width, frame.height).median_depth
        pairs = reference_associations(
            means,
            frame.K,
            frame.world_to_camera,
            frame.width,
            frame.height,
            depth,
            labels,
            tolerance=lengths.depth_tolerance,
            relative=job.spec.params.depth_tolerance_relative,
            near=lengths.visibility_near,
        )
        cached = get_arrays(job.spec.cache_store, job.scene.keys.visibility_key(index))
        assert set(zip(cached["gaussian_ids"].tolist(), cached["mask_ids"].tolist(), strict=True)) == pairs
        llr = log_likelihood_ratio(phi, lik)
        accepted = np.array([any(v >= 0 for v in row) for row in llr.tolist()], dtype=bool)
        increment = np.zeros((n, t), dtype=np.float32)
        for g, m in pairs:
            if accepted[m]:
                increment[g] = llr[m]
                peak[g] = np.maximum(peak[g], margin(phi[m : m + 1], lik.mu0, lik.mu1)[0])
                views[g] += 1
        logodds += increment
        accepted_all.append(accepted)
    return {"logodds": logodds, "peak": peak, "views": views, "accepted": np.concatenate(accepted_all)}


@pytest.fixture(scope="module")
def fused(scene_dir: Path, profile: dict[str, Any], tmp_path_factory: pytest.TempPathFactory) -> dict:
    """One perceive + fuse run with the paper's update and its replay."""
    root = tmp_path_factory.mktemp("fuse-reference")
    job = make_job(scene_dir, root / "job", root / "cache", counting_models(profile))
    run_stage("perceive", job)
    marker = run_stage("fuse", job)
    return {"root": root, "job": job, "marker": marker, "replay": _replay(job)}


def test_fused_state_equals_the_replay(fused: dict) -> None:
    job, replay = fused["job"], fused["replay"]
    assert fused["marker"]["fusion_device"] == "cpu"
    assert fused["marker"]["frames_rendered"] == len(job.scene.selected_frames)
    state = get_arrays(job.spec.store, job.spec.key(FUSION_KEY))
    assert (replay["logodds"] != replay["logodds"][0, 0]).any()  # evidence was fused
    assert not replay["accepted"].all() and replay["accepted"].any()  # OR-phi rejected some masks
    np.testing.assert_array_equal(state["logodds"], replay["logodds"])
    np.testing.assert_array_equal(state["probabilities"], expit(replay["logodds"]).astype(np.float32))
    np.testing.assert_array_equal(state["peak_margin"], replay["peak"])
    accepted = get_arrays(job.spec.store, job.spec.key(ACCEPTED_KEY))
    np.testing.assert_array_equal(accepted["accepted"], replay["accepted"])


def test_view_correlation_divides_evidence_by_the_closed_form(
    fused: dict, scene_dir: Path, profile: dict[str, Any]
) -> None:
    """With rho > 0 each Gaussian's evidence is the paper's divided by 1 + (n - 1) rho for its n
    accepted views: never more evidence than the paper's update, less for Gaussians seen twice+."""
    rho = 0.3
    root, replay = fused["root"], fused["replay"]
    job = make_job(
        scene_dir,
        root / "job-rho",
        root / "cache",  # the first run's caches: same perception and associations
        counting_models(profile),
        params=PipelineParams(view_correlation=rho),
    )
    assert run_stage("fuse", job)["frames_rendered"] == 0
    discounted = get_arrays(job.spec.store, job.spec.key(FUSION_KEY))["logodds"].astype(np.float64)
    base = float(np.float32(logit(PipelineParams().prior)))
    paper = replay["logodds"].astype(np.float64) - base
    expected = base + paper / (1.0 + np.maximum(replay["views"] - 1, 0) * rho)[:, None]
    np.testing.assert_allclose(discounted, expected, rtol=0, atol=1e-5)
    assert np.all(np.abs(discounted - base) <= np.abs(paper) + 1e-5)
    assert (replay["views"] > 1).any() and (np.abs(discounted - base) < 0.5 * np.abs(paper)).any()


def test_fusion_runs_on_the_render_device_unless_told_the_host(
    scene_dir: Path, profile: dict[str, Any], tmp_path: Path
) -> None:
    def device(**params: Any) -> torch.device:
        models = counting_models(profile)
        job = make_job(
            scene_dir, tmp_path / "job", tmp_path / "cache", models, params=PipelineParams(**params)
        )
        return fusion_device(job.spec.params, job.runner)

    assert device() == torch.device("cpu")  # the CLI renders on the CPU unless told otherwise
    assert device(device="cuda") == torch.device("cuda")  # the decision only; no CUDA is touched
    assert device(device="cuda", fusion_backend="cpu") == torch.device("cpu")
    # Parameters written when fusion had a numpy and a torch twin keep meaning where they ran.
    assert PipelineParams(fusion_backend="numpy").fusion_backend == "cpu"
    assert PipelineParams(fusion_backend="torch").fusion_backend == "auto"
    assert device(device="cuda", fusion_backend="numpy") == torch.device("cpu")
