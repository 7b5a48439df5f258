"""Stage 2, `fuse`: visibility of Gaussians per mask, then the Bayesian update (METHOD steps 3-5).

Two halves with different lifetimes:
- mask-to-Gaussian associations depend only on the splat, the camera, the masks and the depth
  settings, so they are cached under a digest of those (the renderer runs once per frame, ever,
  for a given setting);
- the update depends on the task list: it is cheap (one scatter-add per frame) and always re-run.

Outputs (job artifacts): per-Gaussian task probabilities and the per-mask acceptance flags that
the primitive rule needs (a mask rejected by OR-phi forms no primitive).

This module only orchestrates: the arithmetic is `fusion` (one torch implementation, run on the
fusion device: the render device, so a GPU worker's depth never leaves the GPU), the primitives
are `objects.primitives`, rendering is `render`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from bayesian_fields_core.compute.threads import torch_threads
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.fusion.bayes import probability_blocks
from bayesian_fields_core.fusion.likelihood import LikelihoodParams, resolve_likelihood
from bayesian_fields_core.fusion.state import FusedArrays, FusionSettings, FusionState
from bayesian_fields_core.fusion.tensors import as_tensor, fusion_threads, to_numpy
from bayesian_fields_core.fusion.visibility import centre_columns, mask_associations
from bayesian_fields_core.job.artifacts import ACCEPTED_KEY, FUSION_KEY, PRIMITIVES_KEY
from bayesian_fields_core.job.flight import fill_once
from bayesian_fields_core.job.job_scene import JobScene
from bayesian_fields_core.job.markers import write_marker
from bayesian_fields_core.job.runner import Runner
from bayesian_fields_core.job.spec import JobSpec
from bayesian_fields_core.job.store import (
    ARRAY_BLOCK_BYTES,
    ArrayBlocks,
    get_arrays,
    put_array_blocks,
    put_arrays,
)
from bayesian_fields_core.objects.primitives import PrimitiveBuilder
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import Models
from bayesian_fields_core.scene.images import load_depth

log = logging.getLogger(__name__)


def likelihood_params(params: PipelineParams, models: Models) -> LikelihoodParams:
    """Job parameters override the model's calibration, which overrides the paper's defaults."""
    return resolve_likelihood(params, models.calibration)


def fusion_device(params: PipelineParams, runner: Runner) -> torch.device:
    """Where the fusion state lives (`fusion_backend`): the render device ('auto'), so rendered
    depth is used where it was rendered, or the host ('cpu')."""
    return torch.device("cpu" if params.fusion_backend == "cpu" else runner.render_device(params))


class LazyRenderer:
    """The splat's renderer on `device`, built when a frame first needs rendered depth (a job
    whose associations all come from the cache never converts the splat to tensors)."""

    def __init__(self, scene: JobScene, device: str) -> None:
        self._scene = scene
        self._device = device
        self._renderer: Any = None

    def __call__(self) -> Any:
        if self._renderer is None:
            from bayesian_fields_core.render import GaussianRenderer

            self._renderer = GaussianRenderer(
                self._scene.loaded.gaussians,
                device=self._device,
                near_plane=self._scene.lengths.render_near,
            )
        return self._renderer


def frame_depth(params: PipelineParams, renderer: LazyRenderer, frame: Any) -> np.ndarray | torch.Tensor:
    """(H, W) depth for visibility: the input depth image (host array) or the rendered median /
    expected depth (a tensor on the render device)."""
    if params.depth_source == "input":
        depth = load_depth(frame)
        if depth is None:
            raise InputError(
                f"depth_source='input' but frame {frame.name} has no depth image",
                source="parameters.depth_source",
            )
        return depth
    _rgb, expected, median, _alpha = renderer().render_tensors(
        frame.K, frame.world_to_camera, frame.width, frame.height, depth_only=True
    )
    return median if params.depth_source == "median" else expected


@dataclass
class FramePairs:
    """One frame's (Gaussian, mask) pairs: (n,) int64 / int32 tensors on the fusion device, the
    same pairs as host arrays (for the primitive builder and the cache), and whether they were
    computed (a visibility cache miss) rather than read."""

    gaussian_ids: torch.Tensor
    mask_ids: torch.Tensor
    host: tuple[np.ndarray, np.ndarray]
    computed: bool


def _cache_pairs(store: Any, key: str, gaussian_ids: np.ndarray, mask_ids: np.ndarray) -> None:
    put_arrays(
        store,
        key,
        gaussian_ids=gaussian_ids.astype(
            np.uint32 if gaussian_ids.size == 0 or gaussian_ids.max() < 2**32 else np.int64
        ),
        mask_ids=mask_ids.astype(np.int32),
    )


def associations(
    spec: JobSpec,
    scene: JobScene,
    index: int,
    frame: Any,
    labels: np.ndarray,
    renderer: LazyRenderer,
    centres: torch.Tensor,
) -> FramePairs:
    """The pairs of frame `index`, from the scene cache or computed on `centres.device` and cached.

    centres: (3, N) float64 (`visibility.centre_columns`) on the fusion device. Only the pairs (a
    few per cent of the Gaussians) are copied to the host, for the cache and the primitives.
    """
    store = spec.cache_store
    device = centres.device
    key = scene.keys.visibility_key(index)
    if store.exists(key):
        cached = get_arrays(store, key)
        host = (cached["gaussian_ids"], cached["mask_ids"])
        gids = as_tensor(host[0].astype(np.int64), device)
        return FramePairs(gids, as_tensor(host[1].astype(np.int32), device), host, computed=False)
    depth = frame_depth(spec.params, renderer, frame)
    with torch_threads(fusion_threads(device)):
        gids, mids = mask_associations(
            centres,
            frame.K,
            frame.world_to_camera,
            frame.width,
            frame.height,
            depth,
            labels,
            depth_tolerance=scene.lengths.depth_tolerance,
            relative_tolerance=spec.params.depth_tolerance_relative,
            near=scene.lengths.visibility_near,
        )
    host = (to_numpy(gids), to_numpy(mids))
    _cache_pairs(store, key, *host)
    return FramePairs(gids, mids, host, computed=True)


def frame_scores(
    spec: JobSpec, scene: JobScene, index: int, text: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Frame `index`'s label image (H, W) int32 and its masks' cosine scores (M, T) float32 against
    the task texts `text` (T, D), from the perception cache."""
    perception = get_arrays(spec.cache_store, scene.keys.perception_key(index))
    labels = perception["labels"].astype(np.int32)
    phi = perception["embeddings"].astype(np.float32) @ text.T
    return labels, phi


@dataclass
class FrameTally:
    """What the frames leave besides the fusion state: every mask's OR-phi flag in frame order,
    masks per frame, frames whose associations were computed, and the primitives (METHOD step 6,
    built while each frame's pairs are in memory).

    The flags go into one growing buffer, not an array per frame: small arrays kept from every
    frame pin heap memory between the frames' large temporaries, and the process grew by ~0.8 MB
    a frame (scale bench: +230 MB over 300 frames)."""

    primitives: PrimitiveBuilder
    mask_counts: np.ndarray
    accepted: bytearray = field(default_factory=bytearray)
    rendered: int = 0


def fuse_frames(
    spec: JobSpec,
    scene: JobScene,
    runner: Runner,
    frames: Sequence[tuple[int, Any]],
    state: FusionState,
    text: np.ndarray,
) -> FrameTally:
    """Feed every frame to `state` and the primitive builder, reporting progress per frame."""
    num_gaussians = len(scene.loaded.gaussians)
    centres = centre_columns(scene.loaded.gaussians.means, state.device)
    renderer = LazyRenderer(scene, runner.render_device(spec.params))
    tally = FrameTally(PrimitiveBuilder(num_gaussians), np.zeros(len(frames), dtype=np.int64))
    for n, (index, frame) in enumerate(frames):
        runner.check_cancel()
        labels, phi = frame_scores(spec, scene, index, text)
        pairs = associations(spec, scene, index, frame, labels, renderer, centres)
        with torch_threads(fusion_threads(state.device)):
            accepted = state.add_frame(pairs.gaussian_ids, pairs.mask_ids, phi)
        tally.primitives.add_frame(*pairs.host, accepted)
        tally.accepted += accepted.tobytes()
        tally.mask_counts[n] = len(phi)
        tally.rendered += int(pairs.computed)
        runner.progress("fuse", (n + 1) / len(frames))
    return tally


def write_state(spec: JobSpec, fused: FusedArrays) -> None:
    """The per-Gaussian artifact: probabilities, log-odds, peak margins (and `observed` of the
    averaging ablation, `view_counts` of the Bayesian update)."""
    if fused.probabilities is None:
        # Written a block at a time: the (N, T) probabilities are never held beside the log-odds.
        probs: Any = ArrayBlocks(fused.logodds.shape, np.dtype(np.float32), probability_blocks(fused.logodds))
    else:
        probs = fused.probabilities.astype(np.float32)
    optional: dict[str, np.ndarray | ArrayBlocks] = {}
    if fused.observed is not None:
        optional["observed"] = fused.observed
    if fused.view_counts is not None:
        optional["view_counts"] = fused.view_counts
    put_array_blocks(  # uncompressed: float32 state barely compresses (83 -> 50 MB at the scale
        spec.store,  # bench) and zlib cost seconds here and ~0.4 s in `cluster`, which reads it back
        spec.key(FUSION_KEY),
        compress=False,
        block_bytes=ARRAY_BLOCK_BYTES,
        probabilities=probs,
        # Probabilities saturate at 1.0 in float32 after a few dozen agreeing views; the log-odds
        # keep the evidence that ranks saturated objects (selection_score='evidence').
        logodds=fused.logodds.astype(np.float32, copy=False),
        peak_margin=fused.peak,
        **optional,
    )


def write_frames(spec: JobSpec, frames: Sequence[tuple[int, Any]], tally: FrameTally) -> np.ndarray:
    """The per-mask OR-phi flags and the primitives; returns all flags (masks of every frame)."""
    accepted_all = np.frombuffer(tally.accepted, dtype=bool).copy()
    put_arrays(
        spec.store,
        spec.key(ACCEPTED_KEY),
        accepted=accepted_all,
        mask_counts=tally.mask_counts,
        frame_indices=np.array([i for i, _ in frames], dtype=np.int64),
    )
    put_arrays(spec.store, spec.key(PRIMITIVES_KEY), primitive_ids=tally.primitives.primitive_ids)
    return accepted_all


def run(spec: JobSpec, scene: JobScene, runner: Runner) -> dict[str, Any]:
    """The stage: fuse every selected frame, write the state, the flags and the primitives, and
    return the stage marker (timing, counts, where fusion ran, the likelihood used)."""
    t0 = time.perf_counter()
    frames = scene.selected_frames
    text = runner.models.encoder.encode_texts(list(spec.tasks)).astype(np.float32)
    p = spec.params
    lik = likelihood_params(p, runner.models)
    settings = FusionSettings(lik, p.fusion, p.prior, p.outlier_rejection, p.view_correlation)
    device = fusion_device(p, runner)
    state = FusionState(len(scene.loaded.gaussians), len(spec.tasks), settings, device)
    keys = [scene.keys.visibility_key(index) for index, _ in frames]
    scene.record_cache_use("fuse", keys)
    store = spec.cache_store

    # Single flight on the visibility cache: concurrent jobs on this scene render it once.
    def missing() -> bool:
        return any(not store.exists(k) for k in keys)

    with fill_once(runner.flight, "fuse", keys, missing, runner.check_cancel):
        tally = fuse_frames(spec, scene, runner, frames, state, text)
    log.debug(
        "visibility cache: %d hit(s), %d miss(es) in %s",
        len(frames) - tally.rendered,
        tally.rendered,
        scene.keys.visibility_prefix,
    )
    with torch_threads(fusion_threads(state.device)):
        fused = state.finish()
    del state  # a GPU worker's device copy of the state is no longer needed
    write_state(spec, fused)
    accepted_all = write_frames(spec, frames, tally)
    return write_marker(
        spec,
        "fuse",
        {
            "seconds": time.perf_counter() - t0,
            "frames": len(frames),
            "frames_rendered": tally.rendered,
            "gaussians": len(scene.loaded.gaussians),
            "masks": int(tally.mask_counts.sum()),
            "masks_rejected": int((~accepted_all).sum()),
            "fusion_device": str(device),
            "likelihood": {"mu0": lik.mu0, "mu1": lik.mu1, "s": lik.s, "s_eps": lik.s_eps},
            "scene_scale": scene.lengths.record(),
        },
    )
