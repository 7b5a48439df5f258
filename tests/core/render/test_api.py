"""The renderer's public surface: backend choice, resident tensors and input errors."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.render import GaussianRenderer, render
from tests.core.render.scenes import make_gaussians, pinhole

K = pinhole(50.0, 40, 30)


def _scene():
    return make_gaussians([[0.0, 0.0, 2.0], [0.1, 0.0, 3.0]], 0.1)


def test_auto_backend_is_torch_without_gsplat_and_never_imports_it() -> None:
    renderer = GaussianRenderer(_scene(), device="cpu", backend="auto")
    assert renderer.backend == "torch"
    out = renderer.render(K, np.eye(4), 40, 30)
    assert out.rgb.shape == (30, 40, 3) and out.rgb.dtype == np.float32
    assert out.depth.shape == out.median_depth.shape == out.alpha.shape == (30, 40)
    if not torch.cuda.is_available():
        assert "gsplat" not in sys.modules


def test_renderer_renders_many_views_from_resident_tensors() -> None:
    renderer = GaussianRenderer(_scene())
    means_before = renderer.means
    shifted = np.eye(4)
    shifted[0, 3] = 0.2
    a = renderer.render(K, np.eye(4), 40, 30)
    b = renderer.render(K, shifted, 40, 30)
    assert renderer.means is means_before
    assert not np.allclose(a.alpha, b.alpha)
    # The same view twice gives the same image (no state leaks between renders).
    np.testing.assert_array_equal(renderer.render(K, np.eye(4), 40, 30).rgb, a.rgb)


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the no-CUDA error path")
def test_cuda_or_gsplat_without_a_gpu_is_an_input_error() -> None:
    with pytest.raises(InputError, match="device"):
        GaussianRenderer(_scene(), device="cuda")
    with pytest.raises(InputError, match="gsplat"):
        GaussianRenderer(_scene(), backend="gsplat")


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"K": np.eye(4)}, "K"),
        ({"world_to_camera": np.eye(3)}, "world_to_camera"),
        ({"world_to_camera": np.full((4, 4), np.nan)}, "world_to_camera"),
        ({"width": 0}, "width"),
        ({"background": (1.0, 0.0)}, "background"),
    ],
)
def test_bad_camera_input_names_the_field(kwargs: dict, field: str) -> None:
    args = {"K": K, "world_to_camera": np.eye(4), "width": 40, "height": 30} | kwargs
    with pytest.raises(InputError, match=field):
        render(
            _scene(),
            args["K"],
            args["world_to_camera"],
            args["width"],
            args["height"],
            **{k: v for k, v in kwargs.items() if k == "background"},
        )


def test_bad_gaussians_name_the_field() -> None:
    g = _scene()
    g.sh = np.zeros((2, 5, 3), dtype=np.float32)
    with pytest.raises(InputError, match="gaussians.sh"):
        GaussianRenderer(g)
    g = _scene()
    g.quats = g.quats[:, :3]
    with pytest.raises(InputError, match="gaussians.quats"):
        GaussianRenderer(g)
    with pytest.raises(InputError, match="backend"):
        GaussianRenderer(_scene(), backend="opengl")  # type: ignore[arg-type]
