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

import logging
import time
from typing import Any

import numpy as np
from scipy.special import logit

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.fusion.averaging import CosineAverager
from bayesian_fields_core.fusion.bayes import (
    accepted_masks,
    bayes_update,
    discount_correlated_views,
    init_logodds,
    probability_blocks,
)
from bayesian_fields_core.fusion.likelihood import LikelihoodParams, log_likelihood_ratio, resolve_likelihood
from bayesian_fields_core.fusion.peak import (
    init_peak,
    init_peak_torch,
    margin,
    update_peak,
    update_peak_torch,
)
from bayesian_fields_core.fusion.visibility import mask_associations
from bayesian_fields_core.job.artifacts import ACCEPTED_KEY, FUSION_KEY, PRIMITIVES_KEY
from bayesian_fields_core.job.context import JobContext
from bayesian_fields_core.job.markers import write_marker
from bayesian_fields_core.job.store import ArrayBlocks, get_arrays, put_array_blocks, put_arrays
from bayesian_fields_core.objects.primitives import PrimitiveBuilder
from bayesian_fields_core.scene.images import load_depth

log = logging.getLogger(__name__)


def likelihood_params(ctx: JobContext) -> LikelihoodParams:
    """Job parameters override the model's calibration, which overrides the paper's defaults."""
    return resolve_likelihood(ctx.params, ctx.models.calibration)


def _depth_for_frame(ctx: JobContext, renderer_factory: Any, frame: Any) -> np.ndarray:
    if ctx.params.depth_source == "input":
        depth = load_depth(frame)
        if depth is None:
            raise InputError(
                f"depth_source='input' but frame {frame.name} has no depth image",
                source="parameters.depth_source",
            )
        return depth
    # The renderer (torch, resident tensors) is built only when a frame needs rendered depth.
    out = renderer_factory().render(
        frame.K, frame.world_to_camera, frame.width, frame.height, depth_only=True
    )
    return out.median_depth if ctx.params.depth_source == "median" else out.depth


def _cache_pairs(store: Any, key: str, gaussian_ids: np.ndarray, mask_ids: np.ndarray) -> None:
    put_arrays(
        store,
        key,
        gaussian_ids=gaussian_ids.astype(
            np.uint32 if gaussian_ids.size == 0 or gaussian_ids.max() < 2**32 else np.int64
        ),
        mask_ids=mask_ids.astype(np.int32),
    )


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
    _cache_pairs(store, key, gaussian_ids, mask_ids)
    return gaussian_ids, mask_ids, True


def associations_on_device(
    ctx: JobContext, index: int, frame: Any, labels: np.ndarray, renderer_factory, means: Any
) -> tuple:
    """`associations` with the depth image, projection and depth test on `means.device`.

    The rendered depth stays where the renderer left it; only the pairs (a few per cent of the
    Gaussians) are copied to the host, for the scene cache.
    """
    import torch

    from bayesian_fields_core.fusion.visibility_torch import mask_associations_torch

    store = ctx.scene_store
    assert store is not None
    device = means.device
    key = ctx.visibility_key(index)
    if store.exists(key):
        cached = get_arrays(store, key)
        gids = torch.as_tensor(cached["gaussian_ids"].astype(np.int64), device=device)
        return gids, torch.as_tensor(cached["mask_ids"].astype(np.int32), device=device), False
    if ctx.params.depth_source == "input":
        depth = torch.as_tensor(_depth_for_frame(ctx, renderer_factory, frame), device=device)
    else:
        _rgb, expected, median, _alpha = renderer_factory().render_tensors(
            frame.K, frame.world_to_camera, frame.width, frame.height, depth_only=True
        )
        depth = (median if ctx.params.depth_source == "median" else expected).to(device)
    gids, mids = mask_associations_torch(
        means,
        frame.K,
        frame.world_to_camera,
        frame.width,
        frame.height,
        depth,
        torch.as_tensor(labels, device=device),
        depth_tolerance=ctx.params.depth_tolerance,
        relative_tolerance=ctx.params.depth_tolerance_relative,
    )
    _cache_pairs(store, key, gids.cpu().numpy(), mids.cpu().numpy())
    return gids, mids, True


def fusion_on_torch(ctx: JobContext, device: str) -> bool:
    """Whether this job's Bayesian update runs as torch ops on `device` (see `fusion_backend`)."""
    import torch

    backend = ctx.params.fusion_backend
    if ctx.params.fusion != "bayes" or backend == "numpy":
        return False
    return backend == "torch" or torch.device(device).type == "cuda"


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

    device = ctx.params.device or ctx.models.render_device
    on_torch = fusion_on_torch(ctx, device)
    if on_torch:
        import torch

        from bayesian_fields_core.fusion.bayes_torch import bayes_update_torch, init_logodds_torch

        means_t = torch.as_tensor(np.ascontiguousarray(gaussians.means, np.float32), device=device)
        logodds_t = init_logodds_torch(len(gaussians), n_tasks, means_t.device, ctx.params.prior)
    logodds = None if on_torch else init_logodds(len(gaussians), n_tasks, ctx.params.prior)
    # Each Gaussian's best single view per task, for "not found" answers (fusion/peak.py).
    peak = (
        init_peak_torch(len(gaussians), n_tasks, means_t.device)
        if on_torch
        else init_peak(len(gaussians), n_tasks)
    )
    averaging = None if use_bayes else CosineAverager(len(gaussians), n_tasks)

    ctx.record_cache_use("fuse", [ctx.visibility_key(index) for index, _ in frames])
    renderer = None

    def renderer_factory():
        nonlocal renderer
        if renderer is None:
            from bayesian_fields_core.render import GaussianRenderer

            renderer = GaussianRenderer(gaussians, device=device)
        return renderer

    accepted_chunks: list[np.ndarray] = []
    mask_counts = np.zeros(len(frames), dtype=np.int64)
    # Accepted views per Gaussian, only when view_correlation needs them
    # (fusion.bayes.discount_correlated_views); the paper's update never reads them.
    count_views = use_bayes and ctx.params.view_correlation > 0
    view_counts = np.zeros(len(gaussians) if count_views else 0, dtype=np.int32)
    primitives = PrimitiveBuilder(len(gaussians))  # step 6, while each frame's pairs are in memory
    rendered = 0
    for n, (index, frame) in enumerate(frames):
        ctx.check_cancel()
        perception = get_arrays(scene_store, ctx.perception_key(index))
        labels = perception["labels"].astype(np.int32)
        embeddings = perception["embeddings"].astype(np.float32)
        phi = embeddings @ text.T
        llr = log_likelihood_ratio(phi, lik)
        margins = margin(phi, lik.mu0, lik.mu1)
        if on_torch:
            gaussian_ids, mask_ids, was_rendered = associations_on_device(
                ctx, index, frame, labels, renderer_factory, means_t
            )
            accepted = (
                bayes_update_torch(
                    logodds_t,
                    gaussian_ids,
                    mask_ids,
                    torch.as_tensor(llr, device=means_t.device),
                    outlier_rejection=ctx.params.outlier_rejection,
                )
                .cpu()
                .numpy()
            )
            update_peak_torch(
                peak,
                gaussian_ids,
                mask_ids,
                torch.as_tensor(margins, device=means_t.device),
                torch.as_tensor(accepted, device=means_t.device),
            )
            rendered += int(was_rendered)
            accepted_chunks.append(accepted)
            ids_host, masks_host = gaussian_ids.cpu().numpy(), mask_ids.cpu().numpy()
            if count_views:
                view_counts[ids_host[accepted[masks_host]]] += 1
            primitives.add_frame(ids_host, masks_host, accepted)
            mask_counts[n] = len(phi)
            ctx.progress("fuse", (n + 1) / len(frames))
            continue
        gaussian_ids, mask_ids, was_rendered = associations(ctx, index, frame, labels, renderer_factory)
        rendered += int(was_rendered)
        if use_bayes:
            accepted = bayes_update(
                logodds, gaussian_ids, mask_ids, llr, outlier_rejection=ctx.params.outlier_rejection
            )
        else:
            accepted = accepted_masks(llr, ctx.params.outlier_rejection)
            averaging.add_frame(gaussian_ids, mask_ids, phi, accepted)
        update_peak(peak, gaussian_ids, mask_ids, margins, accepted)
        accepted_chunks.append(np.asarray(accepted, dtype=bool))
        if count_views:
            view_counts[gaussian_ids[accepted_chunks[-1][mask_ids]]] += 1  # once per frame at most
        primitives.add_frame(gaussian_ids, mask_ids, accepted_chunks[-1])
        mask_counts[n] = len(phi)
        ctx.progress("fuse", (n + 1) / len(frames))

    log.debug(
        "visibility cache: %d hit(s), %d miss(es) in %s",
        len(frames) - rendered,
        rendered,
        ctx.visibility_prefix,
    )
    if on_torch:
        logodds = logodds_t.cpu().numpy()  # the only host copy of the state: after the last frame
        peak = peak.cpu().numpy()
        del logodds_t
    if use_bayes:
        if count_views:
            discount_correlated_views(logodds, view_counts, ctx.params.view_correlation, ctx.params.prior)
        # Written a block at a time: the (N, T) probabilities are never held beside the log-odds.
        probs: Any = ArrayBlocks(logodds.shape, np.dtype(np.float32), probability_blocks(logodds))
    else:
        probs = averaging.probabilities(lik, unobserved=ctx.params.prior)
        logodds = logit(np.clip(probs.astype(np.float64), 1e-12, 1 - 1e-12)).astype(np.float32)
    observed = None if averaging is None else averaging.counts > 0
    put_array_blocks(  # uncompressed: float32 state barely compresses (83 -> 50 MB at the scale
        ctx.store,  # bench) and zlib cost seconds here and ~0.4 s in `cluster`, which reads it back
        ctx.job_key(FUSION_KEY),
        compress=False,
        probabilities=probs if isinstance(probs, ArrayBlocks) else probs.astype(np.float32),
        # Probabilities saturate at 1.0 in float32 after a few dozen agreeing views; the log-odds
        # keep the evidence that ranks saturated objects (selection_score='evidence').
        logodds=logodds.astype(np.float32, copy=False),
        peak_margin=peak,
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
    put_arrays(ctx.store, ctx.job_key(PRIMITIVES_KEY), primitive_ids=primitives.primitive_ids)
    return write_marker(
        ctx,
        "fuse",
        {
            "seconds": time.perf_counter() - t0,
            "frames": len(frames),
            "frames_rendered": rendered,
            "masks": int(mask_counts.sum()),
            "masks_rejected": int((~accepted_all).sum()),
            "fusion_backend": "torch" if on_torch else "numpy",
            "likelihood": {"mu0": lik.mu0, "mu1": lik.mu1, "s": lik.s, "s_eps": lik.s_eps},
        },
    )
