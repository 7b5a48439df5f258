"""Stage 2, `fuse`: visibility of Gaussians per mask, then the Bayesian update (METHOD steps 3-5).

Two halves with different lifetimes:
- mask-to-Gaussian associations depend only on the splat, the camera, the masks and the depth
  settings, so they are cached under a digest of those (the renderer runs once per frame, ever,
  for a given setting);
- the update depends on the task list: it is cheap (one scatter-add per frame) and always re-run.

Outputs (job artifacts): per-Gaussian task probabilities and the per-mask acceptance flags that
the primitive rule needs (a mask rejected by OR-phi forms no primitive).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from scipy.special import logit

from ..context import JobContext
from ..fusion.averaging import CosineAverager
from ..fusion.bayes import accepted_masks, bayes_update, init_logodds, probabilities
from ..fusion.likelihood import LikelihoodParams, log_likelihood_ratio
from ..fusion.visibility import mask_associations
from ..scene.images import load_depth
from ..store import get_arrays, put_arrays
from .markers import write_marker

FUSION_KEY = "fusion/gaussian_probabilities.npz"
ACCEPTED_KEY = "fusion/accepted_masks.npz"


def likelihood_params(ctx: JobContext) -> LikelihoodParams:
    """Job parameters override the model's calibration, which overrides the paper's defaults."""
    cal = ctx.models.calibration
    p = ctx.params
    return LikelihoodParams(
        mu0=p.mu0 if p.mu0 is not None else float(getattr(cal, "mu0", 0.20)),
        mu1=p.mu1 if p.mu1 is not None else float(getattr(cal, "mu1", 0.27)),
        s=p.s if p.s is not None else float(getattr(cal, "s", 0.035)),
        s_eps=p.s_eps,
    )


def _depth_for_frame(ctx: JobContext, renderer_factory: Any, frame: Any) -> np.ndarray:
    if ctx.params.depth_source == "input":
        depth = load_depth(frame)
        if depth is None:
            raise ValueError(f"depth_source='input' but frame {frame.name} has no depth image")
        return depth
    # The renderer (torch, resident tensors) is built only when a frame needs rendered depth.
    out = renderer_factory().render(
        frame.K, frame.world_to_camera, frame.width, frame.height, depth_only=True
    )
    return out.median_depth if ctx.params.depth_source == "median" else out.depth


def associations(ctx: JobContext, index: int, frame: Any, labels: np.ndarray, renderer_factory) -> tuple:
    """(gaussian_ids, mask_ids) of one frame, from the scene cache or computed and cached."""
    store = ctx.scene_store
    assert store is not None
    key = ctx.visibility_key(index)
    if store.exists(key):
        cached = get_arrays(store, key)
        return cached["gaussian_ids"], cached["mask_ids"], False
    depth = _depth_for_frame(ctx, renderer_factory, frame)
    gaussian_ids, mask_ids = mask_associations(
        ctx.scene().gaussians.means,
        frame.K,
        frame.world_to_camera,
        frame.width,
        frame.height,
        depth,
        labels,
        depth_tolerance=ctx.params.depth_tolerance,
        relative_tolerance=ctx.params.depth_tolerance_relative,
    )
    put_arrays(
        store,
        key,
        gaussian_ids=gaussian_ids.astype(
            np.uint32 if gaussian_ids.size == 0 or gaussian_ids.max() < 2**32 else np.int64
        ),
        mask_ids=mask_ids.astype(np.int32),
    )
    return gaussian_ids, mask_ids, True


def run(ctx: JobContext) -> dict[str, Any]:
    scene_store = ctx.scene_store
    assert scene_store is not None
    t0 = time.perf_counter()
    gaussians = ctx.scene().gaussians
    frames = ctx.selected_frames()
    n_tasks = len(ctx.tasks)
    text = ctx.models.encoder.encode_texts(ctx.tasks).astype(np.float32)
    lik = likelihood_params(ctx)
    use_bayes = ctx.params.fusion == "bayes"

    logodds = init_logodds(len(gaussians), n_tasks, ctx.params.prior)
    averaging = None if use_bayes else CosineAverager(len(gaussians), n_tasks)

    ctx.record_cache_use("fuse", [ctx.visibility_key(index) for index, _ in frames])
    renderer = None

    def renderer_factory():
        nonlocal renderer
        if renderer is None:
            from ..render import GaussianRenderer

            renderer = GaussianRenderer(gaussians, device=ctx.params.device or ctx.models.render_device)
        return renderer

    accepted_chunks: list[np.ndarray] = []
    mask_counts = np.zeros(len(frames), dtype=np.int64)
    rendered = 0
    for n, (index, frame) in enumerate(frames):
        ctx.check_cancel()
        perception = get_arrays(scene_store, ctx.perception_key(index))
        labels = perception["labels"].astype(np.int32)
        embeddings = perception["embeddings"].astype(np.float32)
        gaussian_ids, mask_ids, was_rendered = associations(ctx, index, frame, labels, renderer_factory)
        rendered += int(was_rendered)
        phi = embeddings @ text.T
        llr = log_likelihood_ratio(phi, lik)
        if use_bayes:
            accepted = bayes_update(
                logodds, gaussian_ids, mask_ids, llr, outlier_rejection=ctx.params.outlier_rejection
            )
        else:
            accepted = accepted_masks(llr, ctx.params.outlier_rejection)
            averaging.add_frame(gaussian_ids, mask_ids, phi, accepted)
        accepted_chunks.append(np.asarray(accepted, dtype=bool))
        mask_counts[n] = len(phi)
        ctx.progress("fuse", (n + 1) / len(frames))

    if use_bayes:
        probs = probabilities(logodds)
    else:
        probs = averaging.probabilities(lik, unobserved=ctx.params.prior)
        logodds = logit(np.clip(probs.astype(np.float64), 1e-12, 1 - 1e-12)).astype(np.float32)
    observed = None if averaging is None else averaging.counts > 0
    put_arrays(
        ctx.store,
        ctx.job_key(FUSION_KEY),
        probabilities=probs.astype(np.float32),
        # Probabilities saturate at 1.0 in float32 after a few dozen agreeing views; the log-odds
        # keep the evidence that ranks saturated objects (selection_score='evidence').
        logodds=logodds.astype(np.float32, copy=False),
        **({} if observed is None else {"observed": observed}),
    )
    accepted_all = np.concatenate(accepted_chunks) if accepted_chunks else np.zeros(0, bool)
    put_arrays(
        ctx.store,
        ctx.job_key(ACCEPTED_KEY),
        accepted=accepted_all,
        mask_counts=mask_counts,
        frame_indices=np.array([i for i, _ in frames], dtype=np.int64),
    )
    return write_marker(
        ctx,
        "fuse",
        {
            "seconds": time.perf_counter() - t0,
            "frames": len(frames),
            "frames_rendered": rendered,
            "masks": int(mask_counts.sum()),
            "masks_rejected": int((~accepted_all).sum()),
            "likelihood": {"mu0": lik.mu0, "mu1": lik.mu1, "s": lik.s, "s_eps": lik.s_eps},
        },
    )
