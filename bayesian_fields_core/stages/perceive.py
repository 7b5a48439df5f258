"""Stage 1, `perceive`: segment every frame and embed each mask with CLIP (METHOD steps 1-2).

Outputs are task-independent, so each frame is cached under its image's content digest and the
perception fingerprint (models + parameters): re-running a scene with a new task list, from another
folder, or with one image changed recomputes only the frames whose pixels changed. Frames already
in the cache are skipped one by one, so a crashed stage resumes where it stopped.
The stage starts with the alignment check (`scene/alignment.py`): a splat that does not line up
with its cameras fails the job here, with a one-line reason, before any frame is segmented.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..context import JobContext
from ..perception.crops import embed_masks
from ..scene.images import load_image
from ..store import put_arrays
from .markers import write_marker


def smallest_label_dtype(n_masks: int) -> np.dtype:
    """int16 covers every realistic segmenter output; int32 beyond that."""
    return np.dtype(np.int16) if n_masks < np.iinfo(np.int16).max else np.dtype(np.int32)


def alignment_summary(report: Any) -> dict[str, Any]:
    """The alignment check's headline numbers for the stage report."""
    rendered = report.rendered
    return {
        "score": None if rendered is None else round(rendered.score, 4),
        "frames": 0 if rendered is None else len(rendered.frames),
        "frustum_share": round(report.geometry.frustum_share, 4),
        "extent_ratio": report.geometry.extent_ratio,
        "seconds": round(report.seconds, 3),
    }


def run(ctx: JobContext) -> dict[str, Any]:
    store = ctx.scene_store
    assert store is not None
    # Refuse a splat that does not line up with its cameras before any frame is segmented.
    alignment = ctx.alignment()
    frames = ctx.selected_frames()
    # Built on first need only: a fully cached scene (a re-run with new tasks) loads no model.
    segmenter = encoder = None
    computed = 0
    masks_total = 0
    seg_time = embed_time = 0.0
    t0 = time.perf_counter()
    keys = [ctx.perception_key(index) for index, _ in frames]
    hash_seconds = time.perf_counter() - t0
    ctx.record_cache_use("perceive", keys)
    for n, ((_, frame), key) in enumerate(zip(frames, keys, strict=True)):
        ctx.check_cancel()
        if not store.exists(key):
            if segmenter is None:
                segmenter, encoder = ctx.models.segmenter, ctx.models.encoder
            image = load_image(frame)
            t = time.perf_counter()
            labels = segmenter.segment(image)
            seg_time += time.perf_counter() - t
            t = time.perf_counter()
            embeddings = embed_masks(encoder, image, labels).astype(np.float32)
            embed_time += time.perf_counter() - t
            put_arrays(
                store,
                key,
                labels=labels.astype(smallest_label_dtype(embeddings.shape[0])),
                embeddings=embeddings,
            )
            computed += 1
            masks_total += int(embeddings.shape[0])
        ctx.progress("perceive", (n + 1) / len(frames))
    return write_marker(
        ctx,
        "perceive",
        {
            "seconds": time.perf_counter() - t0,
            "frames": len(frames),
            "frames_computed": computed,
            "frames_cached": len(frames) - computed,
            "masks_computed": masks_total,
            "segment_seconds": seg_time,
            "embed_seconds": embed_time,
            "hash_seconds": hash_seconds,
            "cache_prefix": ctx.perception_prefix,
            "alignment": None if alignment is None else alignment_summary(alignment),
        },
    )
