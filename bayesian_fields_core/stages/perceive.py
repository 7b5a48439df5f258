"""Stage 1, `perceive`: segment every frame and embed each mask with CLIP (METHOD steps 1-2).

Outputs are task-independent, so each frame is cached under its image's content digest and the
perception fingerprint (models + parameters): re-running a scene with a new task list, from another
folder, or with one image changed recomputes only the frames whose pixels changed. Frames already
in the cache are skipped one by one, so a crashed stage resumes where it stopped.
The stage starts with the alignment check (`checks/alignment.py`): a splat that does not line up
with its cameras fails the job here, with a one-line reason, before any frame is segmented.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from bayesian_fields_core.errors import CancelledError
from bayesian_fields_core.job.flight import fill_once
from bayesian_fields_core.job.job_scene import JobScene
from bayesian_fields_core.job.markers import write_marker
from bayesian_fields_core.job.runner import Runner
from bayesian_fields_core.job.spec import JobSpec
from bayesian_fields_core.job.store import put_arrays
from bayesian_fields_core.perception.batching import CropBatcher
from bayesian_fields_core.perception.crops import mask_crops
from bayesian_fields_core.perception.prefetch import pipelined
from bayesian_fields_core.scene.images import load_image

log = logging.getLogger(__name__)


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
        "cached": report.cached,
    }


def run(spec: JobSpec, scene: JobScene, runner: Runner) -> dict[str, Any]:
    """Segment and embed every frame not yet in the perception cache.

    Decoding, segmentation and cropping run ahead in threads (`pipelined`, at most
    `prefetch_frames` frames per step), and crops of consecutive frames are encoded together in
    batches of `crop_batch_size` (`CropBatcher`); each frame is written once its last crop is
    encoded, so a crash still resumes frame by frame.
    """
    t0 = time.perf_counter()
    store = spec.cache_store
    params = spec.params
    # Refuse a splat that does not line up with its cameras before any frame is segmented.
    alignment = scene.alignment(runner.render_device(params))
    frames = scene.selected_frames
    t_hash = time.perf_counter()
    keys = {index: scene.keys.perception_key(index) for index, _ in frames}
    hash_seconds = time.perf_counter() - t_hash
    scene.record_cache_use("perceive", list(keys.values()))
    todo = [(n, index, frame) for n, (index, frame) in enumerate(frames)]
    todo = [t for t in todo if not store.exists(keys[t[1]])]
    done_frames = len(frames) - len(todo)
    log.debug(
        "perception cache: %d hit(s), %d miss(es) in %s", done_frames, len(todo), scene.keys.perception_prefix
    )
    masks_total = 0
    timings = {"decode": 0.0, "segment": 0.0, "crop": 0.0, "embed": 0.0}
    batcher = None

    # Single flight: of the jobs that start together on this scene and models, one computes the
    # missing frames; the others wait for it, then find them cached (`job/flight.py`).
    def missing() -> bool:
        return bool(todo)

    with fill_once(runner.flight, "perceive", sorted(keys.values()), missing, runner.check_cancel):
        todo = [t for t in todo if not store.exists(keys[t[1]])]  # what a flight before us left
        done_frames = len(frames) - len(todo)
        if todo:
            # Built on first need only, in this thread: a fully cached scene loads no model, and each
            # model is then used from one thread only (the segmenter in its step, the encoder here).
            runner.models.load("segmenter", "encoder")
            segmenter, encoder = runner.models.segmenter, runner.models.encoder
            batcher = CropBatcher(encoder, params.crop_batch_size)

            def timed(name: str, fn: Any) -> Any:
                def step(item: tuple) -> tuple:
                    t = time.perf_counter()
                    out = fn(item)
                    timings[name] += time.perf_counter() - t
                    return out

                return step

            steps = [
                timed("decode", lambda it: (it[0], load_image(it[1]))),
                timed("segment", lambda it: (it[0], it[1], segmenter.segment(it[1]))),
                timed("crop", lambda it: (it[0], it[2], mask_crops(it[1], it[2]))),
            ]

            def write(index: int, labels: np.ndarray, embeddings: np.ndarray) -> None:
                nonlocal masks_total, done_frames
                put_arrays(
                    store,
                    keys[index],
                    labels=labels.astype(smallest_label_dtype(embeddings.shape[0])),
                    embeddings=embeddings.astype(np.float32),
                )
                masks_total += int(embeddings.shape[0])
                done_frames += 1
                runner.progress("perceive", done_frames / len(frames))

            for index, labels, crops in pipelined(
                ((index, frame) for _n, index, frame in todo), steps, params.prefetch_frames
            ):
                try:
                    runner.check_cancel()
                except CancelledError:
                    # Frames already received are finished and cached, so a resume skips them.
                    for (i, lab), emb in batcher.flush():
                        write(i, lab, emb)
                    raise
                t = time.perf_counter()
                ready = list(batcher.add((index, labels), crops))
                timings["embed"] += time.perf_counter() - t
                for (i, lab), emb in ready:
                    write(i, lab, emb)
            t = time.perf_counter()
            ready = list(batcher.flush())
            timings["embed"] += time.perf_counter() - t
            for (i, lab), emb in ready:
                write(i, lab, emb)
    runner.progress("perceive", 1.0)
    return write_marker(
        spec,
        "perceive",
        {
            "seconds": time.perf_counter() - t0,
            "frames": len(frames),
            "frames_computed": len(todo),
            "frames_cached": len(frames) - len(todo),
            "masks_computed": masks_total,
            "decode_seconds": timings["decode"],
            "segment_seconds": timings["segment"],
            "crop_seconds": timings["crop"],
            "embed_seconds": timings["embed"],
            "encoder_calls": 0 if batcher is None else batcher.calls,
            "crop_batch_size": params.crop_batch_size,
            "hash_seconds": hash_seconds,
            "cache_prefix": scene.keys.perception_prefix,
            "alignment": None if alignment is None else alignment_summary(alignment),
        },
    )
