"""bench/gpu_check_fidelity.py, the renderer comparison a GPU run of gpu_check prints (our torch
rasteriser against gsplat), exercised on the CPU: our renderer against itself must agree exactly,
and against a renderer with known faults the figures must show exactly those faults."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from bayesian_fields_core.fusion.likelihood import LikelihoodParams
from bayesian_fields_core.fusion.state import FusionSettings
from bayesian_fields_core.fusion.visibility import DEFAULT_NEAR
from bayesian_fields_core.render import GaussianRenderer

from .scenes import make_gaussians, pinhole

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "bench"))
import gpu_check_fidelity as fidelity  # noqa: E402 - a bench script's module, not a package

W, H, TASKS = 48, 36, 3
SETTINGS = FusionSettings(LikelihoodParams(), "bayes", 0.05, True, 0.0)


@pytest.fixture(scope="module")
def scene():
    """Two textured walls at depths 2 and 3 seen by three cameras; 4 x 3 block masks, random scores."""
    rng = np.random.default_rng(5)
    near = np.c_[rng.uniform(-0.6, 0.0, 1500), rng.uniform(-0.6, 0.6, 1500), np.full(1500, 2.0)]
    far = np.c_[rng.uniform(-1.5, 1.5, 2500), rng.uniform(-1.2, 1.2, 2500), np.full(2500, 3.0)]
    gaussians = make_gaussians(
        np.r_[near, far], 0.03, colours=rng.uniform(0.1, 0.9, (4000, 3)), opacities=0.95
    )
    frames = []
    for i, shift in enumerate((-0.1, 0.0, 0.1)):
        w2c = np.eye(4)
        w2c[0, 3] = shift
        frames.append((i, SimpleNamespace(K=pinhole(40.0, W, H), world_to_camera=w2c, width=W, height=H)))
    labels = (np.arange(H)[:, None] // 12) * 4 + (np.arange(W)[None, :] // 12)
    phi = {i: rng.normal(0.22, 0.04, (12, TASKS)).astype(np.float32) for i, _ in frames}

    def scores(index: int) -> tuple[np.ndarray, np.ndarray]:
        return labels.astype(np.int32), phi[index]

    return gaussians, frames, scores


def _compare(scene, candidate) -> fidelity.Fidelity:
    gaussians, frames, scores = scene
    ours = GaussianRenderer(gaussians, backend="torch")
    return fidelity.compare_renderers(
        frames,
        ours,
        candidate(ours),
        gaussians.means,
        scores,
        SETTINGS,
        num_tasks=TASKS,
        depth_tolerance=0.05,
        relative_tolerance=0.03,
        near=DEFAULT_NEAR,
        device="cpu",
    )


@pytest.mark.slow
def test_the_same_renderer_on_both_sides_agrees_exactly(scene) -> None:
    fid = _compare(scene, lambda ours: ours)
    d = fid.as_dict()
    assert d["frames"] == 3 and d["psnr_frames_identical"] == 3 and math.isinf(d["psnr_db_median"])
    for depth in (d["expected_depth"], d["median_depth"]):
        assert depth["pixels_both"] > 1000 and depth["median_abs"] == 0.0
        assert depth["within_tolerance"] == 1.0 and depth["only_one_share"] == 0.0
    assert d["pairs"]["jaccard"] == 1.0 and d["pairs"]["union"] > 500
    assert d["logodds"]["gaussians"] > 500 and d["logodds"]["max_abs"] == 0.0
    assert d["logodds"]["top_task_same"] == 1.0
    assert len(fidelity.report_lines(fid)) == 5


class FaultyRenderer:
    """Our renderer with known faults: colour x 0.9, every depth 0.2 further away."""

    def __init__(self, inner: GaussianRenderer) -> None:
        self.inner = inner

    def render_tensors(self, K, w2c, width, height):  # noqa: ANN001
        rgb, depth, median, alpha = self.inner.render_tensors(K, w2c, width, height)
        shift = lambda d: torch.where(d > 0, d + 0.2, d)  # noqa: E731
        return rgb * 0.9, shift(depth), shift(median), alpha


@pytest.mark.slow
def test_known_faults_show_in_every_figure(scene) -> None:
    gaussians, frames, _ = scene
    ours = GaussianRenderer(gaussians, backend="torch")
    rgb = ours.render_tensors(frames[0][1].K, frames[0][1].world_to_camera, W, H)[0].double()
    expected_psnr = 10 * math.log10(1.0 / float(((0.1 * rgb) ** 2).mean()))
    fid = _compare(scene, FaultyRenderer)
    assert fid.psnr_db[0] == pytest.approx(expected_psnr, abs=1e-4)  # rgb * 0.9 rounds in float32
    d = fid.as_dict()
    assert d["psnr_frames_identical"] == 0
    for depth in (d["expected_depth"], d["median_depth"]):
        assert depth["median_abs"] == pytest.approx(0.2, abs=1e-5)
        # 0.2 exceeds the tolerance 0.05 + 0.03 d at the walls' depths (2 and 3)
        assert depth["within_tolerance"] == 0.0 and depth["only_one_share"] == 0.0
    # No centre lies within the tolerance of a depth 0.2 behind the surface: the candidate sees none,
    # so its log-odds stay at the prior and differ from ours by all of our evidence.
    assert d["pairs"]["jaccard"] == 0.0 and d["pairs"]["union"] > 500
    reference = _compare(scene, lambda ours: ours).as_dict()["logodds"]
    assert d["logodds"]["gaussians"] == reference["gaussians"] > 0
    assert d["logodds"]["max_abs"] > 0 and d["logodds"]["sign_same"] < 1.0


def test_psnr_and_jaccard_by_hand() -> None:
    assert fidelity.psnr(torch.zeros(4, 4, 3), torch.full((4, 4, 3), 0.1)) == pytest.approx(20.0)
    a = fidelity.pair_keys(torch.tensor([1, 2, 3]), torch.tensor([0, 1, 1]), 4)
    b = fidelity.pair_keys(torch.tensor([2, 3, 4]), torch.tensor([1, 0, 1]), 4)
    assert fidelity.jaccard(a, b) == (1, 5)  # only (2, 1) in both
