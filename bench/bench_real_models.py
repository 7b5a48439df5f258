"""CPU figures of the real-size perception models, and a whole-scene estimate from them.

What it measures, each through the user's code path (`perception.models.load_models` on the reference
profiles that `scripts/make_reference_models.py` writes, i.e. the perception registry; the
segmenter's `segment`, `perception.crops.mask_crops` and the perceive stage's `CropBatcher` with
the configured `crop_batch_size`, so preprocessing and batching are included):

- FastSAM frames/s for each reference scale (FastSAM-x: YOLOv8x-seg, FastSAM-s: YOLOv8s-seg; one
  class) at the profile's settings (imgsz 640, retina masks) on 640x480 frames (the sample's
  320x240 renders upscaled);
- CLIP ViT-B/16 crops/s through each encoder of the same weights: transformers (torch), open_clip
  (torch) and ONNX (onnxruntime), fed full batches of `crop_batch_size` crops cut from ~100
  synthetic masks per frame (random FastSAM weights propose few or no masks, so the crops cannot
  come from them);
- cropping ms per frame (`mask_crops`, ~100 masks);
- the whole-scene estimate for the scale bench scene (400k Gaussians, 300 frames at 640x480, ~100
  masks per frame, 26 tasks): frames / (frames/s) + crops / (crops/s) + cropping, plus fuse and
  cluster from the figures given on the command line (defaults: this machine's scale-bench
  figures, see `--fuse-s-per-frame`). On a CPU the perception threads share the same cores, so
  the steps add up; nothing overlaps for free.

Weights are random (no download is possible here); speed and memory do not depend on them.
Run in the second venv (scripts/make_reference_venv.sh):
  PYTHONPATH=. /tmp/venv-tv/bin/python bench/bench_real_models.py --models DIR [--frames 3]
      [--batches 3] [--masks 100]
Iterations are bounded (one warm-up + `--frames` frames per segmenter, one warm-up batch +
`--batches` batches per encoder): a few minutes on 2 CPU cores. HOME-writing tools (ultralytics,
Hugging Face, onnxruntime) are pointed at a temp folder.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

_TMP_HOME = Path(tempfile.mkdtemp(prefix="bfields-bench-real-"))
for _var, _sub in (
    ("HOME", "home"),
    ("YOLO_CONFIG_DIR", "yolo"),
    ("HF_HOME", "hf"),
    ("XDG_CACHE_HOME", "cache"),
):
    os.environ[_var] = str(_TMP_HOME / _sub)
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("YOLO_OFFLINE", "1")

import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bayesian_fields_core.params import PipelineParams  # noqa: E402
from bayesian_fields_core.perception.batching import CropBatcher  # noqa: E402
from bayesian_fields_core.perception.crops import mask_crops  # noqa: E402
from bayesian_fields_core.perception.masks import exclusive_labels  # noqa: E402
from bayesian_fields_core.perception.models import load_models  # noqa: E402

WIDTH, HEIGHT = 640, 480
PROFILES = {  # profile file -> (segmenter label, encoder label), as make_reference_models writes them
    "reference-fastsam-hf-clip.yaml": ("FastSAM-x", "ViT-B/16 transformers (torch)"),
    "reference-fastsam-open-clip.yaml": ("FastSAM-s", "ViT-B/16 open_clip (torch)"),
    "reference-fastsam-onnx-clip.yaml": ("FastSAM-s", "ViT-B/16 ONNX (onnxruntime)"),
}


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def frames_640x480(n: int) -> list[np.ndarray]:
    """(480, 640, 3) uint8 frames: the tabletop sample's renders, upscaled."""
    paths = sorted((ROOT / "samples" / "tabletop" / "images").glob("*.png"))[:n]
    return [np.asarray(Image.open(p).convert("RGB").resize((WIDTH, HEIGHT), Image.BILINEAR)) for p in paths]


def synthetic_labels(m: int, rng: np.random.Generator) -> np.ndarray:
    """(H, W) exclusive labels of `m` overlapping rectangles/ellipses, 0.05 % to 40 % of the
    frame (FastSAM-like sizes), made exclusive by the project's own rule (smallest wins)."""
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    cy, cx = rng.uniform(0, HEIGHT, m), rng.uniform(0, WIDTH, m)
    ry = np.exp(rng.uniform(np.log(4), np.log(HEIGHT / 2), m))
    rx = ry * rng.uniform(0.5, 2.0, m)
    ellipse = rng.random(m) < 0.5
    dy = (yy[None] - cy[:, None, None]) / ry[:, None, None]
    dx = (xx[None] - cx[:, None, None]) / rx[:, None, None]
    masks = np.where(ellipse[:, None, None], dy**2 + dx**2 <= 1, (np.abs(dy) <= 1) & (np.abs(dx) <= 1))
    return exclusive_labels(masks, min_area=100)


def bench_segmenter(segmenter, images: list[np.ndarray]) -> dict:
    """One warm-up frame, then each of `images[1:]` once: median s/frame, masks per frame."""
    segmenter.segment(images[0])
    times, masks = [], []
    cpu = cpu_seconds()
    for image in images[1:]:
        t = time.perf_counter()
        labels = segmenter.segment(image)
        times.append(time.perf_counter() - t)
        masks.append(int(labels.max()) + 1)
    return {
        "s_per_frame": statistics.median(times),
        "cpu_per_frame": (cpu_seconds() - cpu) / len(times),
        "masks": statistics.median(masks),
        "n": len(times),
    }


def bench_encoder(encoder, crops_per_frame: list[list[np.ndarray]], batch_size: int, batches: int) -> dict:
    """Feed frames' crops through the stage's `CropBatcher` until `batches` full batches after a
    warm-up batch have been encoded; median seconds per batch -> crops/s."""
    batcher = CropBatcher(encoder, batch_size)
    calls_before, times, cpu_used = 0, [], 0.0
    frame = 0
    while len(times) < batches:
        t, cpu = time.perf_counter(), cpu_seconds()
        list(batcher.add(frame, crops_per_frame[frame % len(crops_per_frame)]))
        elapsed, cpu_elapsed = time.perf_counter() - t, cpu_seconds() - cpu
        frame += 1
        new_calls = batcher.calls - calls_before
        calls_before = batcher.calls
        if new_calls == 0:
            continue
        if batcher.calls == new_calls:  # the first call(s) warm up (allocation, ORT graph init)
            continue
        times.extend([elapsed / new_calls] * new_calls)
        cpu_used += cpu_elapsed
    per_batch = statistics.median(times)
    return {
        "crops_per_s": batch_size / per_batch,
        "s_per_batch": per_batch,
        "cpu_per_crop": cpu_used / (len(times) * batch_size),
        "batches": len(times),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", type=Path, required=True, help="make_reference_models.py output")
    parser.add_argument("--frames", type=int, default=3, help="timed frames per FastSAM (after 1 warm-up)")
    parser.add_argument(
        "--batches", type=int, default=3, help="timed crop batches per encoder (after warm-up)"
    )
    parser.add_argument("--masks", type=int, default=100, help="synthetic masks per frame for the crops")
    parser.add_argument("--scene-frames", type=int, default=300)
    parser.add_argument("--scene-masks", type=int, default=100, help="masks per frame of the scale scene")
    parser.add_argument(
        "--fuse-s-per-frame",
        type=float,
        default=3.5,
        help="fuse s/frame with depth rendered on the CPU (README 'Measured figures': 3.2-3.7 s)",
    )
    parser.add_argument(
        "--cluster-s", type=float, default=6.35, help="cluster stage s at the scale bench (README: 6.35 s)"
    )
    parser.add_argument("--only", help="comma-separated profile names to run (default: all three)")
    args = parser.parse_args(argv)
    import torch

    params = PipelineParams()
    batch_size = params.crop_batch_size
    print(
        f"real-size perception on the CPU: torch {torch.__version__}, {torch.get_num_threads()} threads, "
        f"{os.cpu_count()} cores, load {os.getloadavg()[0]:.2f} at start; crop_batch_size {batch_size}"
    )
    images = frames_640x480(args.frames + 1)
    rng = np.random.default_rng(0)
    labels = [synthetic_labels(args.masks, rng) for _ in range(2)]
    t = time.perf_counter()
    crops = [mask_crops(images[i % len(images)], lab) for i, lab in enumerate(labels)]
    crop_ms = 1000 * (time.perf_counter() - t) / len(labels)
    crop_sizes = [c.shape[0] for frame in crops for c in frame]
    print(
        f"  crops: {sum(len(c) for c in crops) / len(crops):.0f} per frame, {crop_ms:.0f} ms/frame to cut "
        f"(side median {np.median(crop_sizes):.0f} px)"
    )

    seg_results: dict[str, dict] = {}
    enc_results: dict[str, dict] = {}
    for name, (seg_label, enc_label) in PROFILES.items():
        if args.only and name.removesuffix(".yaml") not in args.only.split(","):
            continue
        path = args.models / "profiles" / name
        if not path.is_file():
            print(f"  {name}: missing, skipped")
            continue
        models = load_models(path)
        if seg_label not in seg_results:
            t = time.perf_counter()
            segmenter = models.segmenter
            load = time.perf_counter() - t
            r = bench_segmenter(segmenter, images)
            r["load_s"] = load
            seg_results[seg_label] = r
            print(
                f"  {seg_label:<10} {1 / r['s_per_frame']:6.2f} frames/s  ({r['s_per_frame']:.2f} s/frame median of "
                f"{r['n']}, CPU {r['cpu_per_frame']:.2f} s/frame; imgsz {segmenter.imgsz}, "
                f"{r['masks']:.0f} masks/frame from random weights; load {load:.1f} s)"
            )
        t = time.perf_counter()
        encoder = models.encoder
        load = time.perf_counter() - t
        r = bench_encoder(encoder, crops, batch_size, args.batches)
        r["load_s"] = load
        enc_results[enc_label] = r
        print(
            f"  {enc_label:<32} {r['crops_per_s']:6.1f} crops/s  ({r['s_per_batch']:.2f} s per batch of "
            f"{batch_size}, median of {r['batches']}; CPU {1000 * r['cpu_per_crop']:.0f} ms/crop; load {load:.1f} s)"
        )
        del models, encoder

    n_f, n_m = args.scene_frames, args.scene_masks
    n_crops = n_f * n_m
    print(
        f"whole-scene estimate, scale bench scene ({n_f} frames at {WIDTH}x{HEIGHT}, {n_m} masks/frame = "
        f"{n_crops:,} crops, 400k Gaussians, 26 tasks), this CPU:"
    )
    fuse = n_f * args.fuse_s_per_frame
    for seg_label, seg in seg_results.items():
        for enc_label, enc in enc_results.items():
            segment = n_f * seg["s_per_frame"]
            embed = n_crops / enc["crops_per_s"]
            cut = n_f * crop_ms / 1000
            total = segment + embed + cut + fuse + args.cluster_s
            print(
                f"  {seg_label} + {enc_label:<32} {total / 60:6.1f} min = segment {segment:6.0f} s + embed "
                f"{embed:6.0f} s + crop {cut:4.0f} s + fuse {fuse:4.0f} s + cluster {args.cluster_s:.1f} s"
            )
    print(f"  (fuse {args.fuse_s_per_frame} s/frame and cluster {args.cluster_s} s from the command line)")
    print(f"load {os.getloadavg()[0]:.2f} at end; process CPU {cpu_seconds():.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
