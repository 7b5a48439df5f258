"""Benchmark the CPU parts of perception per frame: mask exclusivity, classical segmentation,
masked crops, and embedding all crops of a frame in one batch.

Synthetic: a 480 x 640 image of smooth noise with ~100 rectangles and ellipses as overlapping
FastSAM-like masks (sizes from 0.05 % to 40 % of the frame). The CLIP is a random tiny CLIPModel
(the real cost of a ViT-B/16 is dominated by the model and belongs on the GPU); it measures our
preprocessing + batching overhead.
Usage: python bench/bench_perception.py [--masks 100] [--repeat 7]
Targets: exclusive_labels < 50 ms, mask_crops < 20 ms, classical segmentation < 1 s per frame.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bayesian_fields_core.perception.classical import ClassicalSegmenter
from bayesian_fields_core.perception.crops import embed_masks, mask_crops
from bayesian_fields_core.perception.hf_clip import HFClipEncoder
from bayesian_fields_core.perception.masks import exclusive_labels


def synthetic_masks(m: int, h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w]
    cy, cx = rng.uniform(0, h, m), rng.uniform(0, w, m)
    ry = np.exp(rng.uniform(np.log(4), np.log(h / 2), m))
    rx = ry * rng.uniform(0.5, 2.0, m)
    ellipse = rng.random(m) < 0.5
    dy = (yy[None] - cy[:, None, None]) / ry[:, None, None]
    dx = (xx[None] - cx[:, None, None]) / rx[:, None, None]
    return np.where(ellipse[:, None, None], dy**2 + dx**2 <= 1, (np.abs(dy) <= 1) & (np.abs(dx) <= 1))


def median_ms(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1000 * statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--masks", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    h, w = 480, 640
    masks = synthetic_masks(args.masks, h, w, rng)
    noise = rng.random((h // 16, w // 16, 3))
    image = (np.kron(noise, np.ones((16, 16, 1))) * 255).astype(np.uint8)
    labels = exclusive_labels(masks, min_area=100)
    print(f"frame {w}x{h}, {args.masks} masks -> {labels.max() + 1} exclusive labels")
    print(f"exclusive_labels   median {median_ms(lambda: exclusive_labels(masks, 100), args.repeat):8.1f} ms")
    print(f"mask_crops         median {median_ms(lambda: mask_crops(image, labels), args.repeat):8.1f} ms")
    seg = ClassicalSegmenter()
    print(f"classical segment  median {median_ms(lambda: seg.segment(image), args.repeat):8.1f} ms")

    from tests.core.perception.conftest import make_tiny_clip

    with tempfile.TemporaryDirectory() as tmp:
        enc = HFClipEncoder(make_tiny_clip(Path(tmp) / "tiny-clip"))
        ms = median_ms(lambda: embed_masks(enc, image, labels), args.repeat)
        print(f"embed_masks (tiny) median {ms:8.1f} ms for {labels.max() + 1} crops in one batch")


if __name__ == "__main__":
    main()
