"""Scale benchmark of the real `fuse` and `cluster` stages at the paper's size, on the CPU.

Issue spec: a generated scene of 400k Gaussians, 300 frames at 640x480, ~100 masks per frame and
26 tasks; report per-stage time and peak memory. Aims: fuse < 0.5 s per frame, cluster
(primitives to results) < 10 s (issue 11 item 7: < 2 s with `--outputs arrays`), AIB on ~2,000
primitives < 1 s.

What is real and what is synthetic:
- the stages are the pipeline's own `run_stage("fuse")` and `run_stage("cluster")` on a
  job built by `job.factories.local_job` (local stores), reading a real scene folder (binary .ply + transforms.json);
- the perception cache they read is synthetic: an ideal segmenter over the Gaussian centres
  z-buffered into each view (a pixel shows the part of its nearest centre): parts are the 60
  blobs and a 10 x 10 grid of floor cells, ~100 masks per frame, with granularity varying from
  frame to frame (blob halves, merged floor cells) as a real segmenter's does; 512-d unit
  embeddings whose cosines with the task texts are drawn from N(0.20, 0.035) (irrelevant) or
  N(0.27, 0.035) (the mask's blob belongs to that task), the paper's calibration;
- the text encoder is a deterministic stand-in returning fixed embeddings for the 26 task
  strings (no CLIP is loaded; perception is not what this measures).
- depth for visibility: `--depth render` renders median depth with the project's renderer (the
  stage's default path); `--depth synthetic` z-buffers the Gaussian centres with numpy (at a
  quarter resolution, upsampled) into per-frame depth files and runs fuse with
  `depth_source='input'`, so fuse's cost without rendering shows separately.

Setup runs in a child process so the peak RSS printed is that of loading the scene + fuse +
cluster only. The cluster stage runs with the pipeline's default outputs (`--outputs full`: result
arrays, .ply exports and previews) or without exports and previews (`--outputs arrays`); its
per-step wall and process-CPU seconds are printed. `--cluster-only --repeats N` reruns just the
cluster stage N times on the fused state a `--keep` run left and prints per-step medians (it keeps
that work folder whether or not `--keep` is given).
Usage:
  python bench/bench_scale.py [--gaussians 400000] [--frames 300] [--depth synthetic|render]
                              [--masks 100] [--tasks 26] [--workdir DIR] [--keep]
                              [--outputs full|arrays] [--cluster-only --repeats 3]
Times are wall seconds on the machine as it is (other work shares the cores): process-CPU
seconds are printed too.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from bayesian_fields_core.geometry.transforms import look_at, pinhole
from bayesian_fields_core.job.content_keys import perception_input_digest
from bayesian_fields_core.job.factories import Job, local_job
from bayesian_fields_core.job.pipeline import run_stage
from bayesian_fields_core.job.runner import ProgressFn, no_progress
from bayesian_fields_core.job.store import LocalStore, put_arrays
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.results.reader import read_result
from bayesian_fields_core.scene.nerfstudio import write_transforms
from bayesian_fields_core.scene.ply import write_ply
from bayesian_fields_core.scene.types import Frame, Gaussians
from bayesian_fields_core.stages.perceive import smallest_label_dtype

EMBED_DIM = 512
MU0, MU1 = 0.20, 0.27  # target cosine of irrelevant / relevant masks (paper's calibration)
NOISE_STD = 0.035  # spread of the cosines around those means (paper's s)
N_BLOBS = 60
NO_TASK = -1
DEPTH_DOWNSAMPLE = 4
MIN_MASK_CELLS = 4  # smallest mask kept, in z-buffer cells (64 full-resolution pixels)
SCENE_PREFIX = "scenes/bench/"
FINGERPRINT = "bench-synthetic-perception"


# --------------------------------------------------------------------------------------------
# Synthetic inputs
# --------------------------------------------------------------------------------------------
@dataclass
class Parts:
    """What an ideal segmenter would cut the scene into: each blob, and the floor in a grid of
    cells. blob_of / cell_of: (N,) part of each Gaussian (-1 when on the other kind); lower: (N,)
    the Gaussian is on its blob's lower half (some frames segment the halves separately)."""

    blob_of: np.ndarray
    cell_of: np.ndarray
    lower: np.ndarray
    grid: int
    blob_centres: np.ndarray


def make_gaussians(n: int, grid: int, rng: np.random.Generator) -> tuple[Gaussians, Parts]:
    """A 5 x 5 m floor (a quarter of the points, cut into grid x grid cells) and N_BLOBS spheres
    resting on it, each sphere's point count proportional to its area."""
    angle = rng.uniform(0, 2 * np.pi, N_BLOBS)
    radius = 1.6 * np.sqrt(rng.uniform(0, 1, N_BLOBS))
    sizes = rng.uniform(0.08, 0.3, N_BLOBS)
    centres = np.stack([radius * np.cos(angle), radius * np.sin(angle), sizes], axis=1)
    n_floor = n // 4
    floor_xy = rng.uniform(-2.5, 2.5, (n_floor, 2))
    floor = np.column_stack([floor_xy, np.zeros(n_floor)])
    blob = rng.choice(N_BLOBS, size=n - n_floor, p=sizes**2 / (sizes**2).sum())
    direction = rng.normal(size=(n - n_floor, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    on_blobs = centres[blob] + sizes[blob, None] * direction
    means = np.concatenate([floor, on_blobs]).astype(np.float32)
    cell_xy = np.minimum(((floor_xy + 2.5) / 5.0 * grid).astype(np.int64), grid - 1)
    parts = Parts(
        blob_of=np.concatenate([np.full(n_floor, -1), blob]),
        cell_of=np.concatenate([cell_xy[:, 1] * grid + cell_xy[:, 0], np.full(n - n_floor, -1)]),
        lower=np.concatenate([np.zeros(n_floor, bool), direction[:, 2] < 0]),
        grid=grid,
        blob_centres=centres,
    )
    gaussians = Gaussians(
        means=means,
        log_scales=np.log(np.full((n, 3), [0.01, 0.01, 0.002], dtype=np.float32)),
        quats=np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
        opacity_logits=np.full(n, 2.0, dtype=np.float32),
        sh=rng.normal(0, 0.3, (n, 1, 3)).astype(np.float32),
    )
    return gaussians, parts


def make_frames(n_frames: int, width: int, height: int, images: Path) -> list[Frame]:
    """An orbit of cameras at two heights looking at the scene centre; placeholder image files
    (the loader checks they exist; fuse and cluster never read them), each a different colour
    because the perception cache is keyed on image content."""
    K = pinhole(width, height, 60.0)
    frames = []
    for i in range(n_frames):
        azimuth = 2 * np.pi * i / n_frames
        eye = np.array([3.2 * np.cos(azimuth), 3.2 * np.sin(azimuth), 1.4 if i % 2 else 1.9])
        path = images / f"frame_{i:05d}.png"
        Image.new("RGB", (8, 8), (i % 256, i // 256 % 256, i // 65536 % 256)).save(path)
        frames.append(
            Frame(f"frame_{i:05d}", K, look_at(eye, np.array([0.0, 0.0, 0.2])), width, height, path)
        )
    return frames


def project(points: np.ndarray, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """(pixel xy (n, 2), camera depth (n,)) of world points."""
    cam = points @ frame.world_to_camera[:3, :3].T + frame.world_to_camera[:3, 3]
    z = cam[:, 2]
    uv = cam[:, :2] / np.maximum(z, 1e-9)[:, None] * np.diag(frame.K)[:2] + frame.K[:2, 2]
    return uv, z


def zbuffer(means: np.ndarray, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """(nearest Gaussian (h, w) int64, -1 = none; its depth (h, w) float32, 0 = none) per pixel of
    a 1/DEPTH_DOWNSAMPLE resolution grid: the closest centre wins (sort by pixel then depth)."""
    step = DEPTH_DOWNSAMPLE
    w, h = -(-frame.width // step), -(-frame.height // step)
    uv, z = project(means, frame)
    px = np.floor(uv / step).astype(np.int64)
    ok = np.flatnonzero((z > 0.05) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h))
    pixel = px[ok, 1] * w + px[ok, 0]
    order = np.lexsort((z[ok], pixel))
    first = np.unique(pixel[order], return_index=True)[1]
    nearest = np.full(w * h, -1, dtype=np.int64)
    depth = np.zeros(w * h, dtype=np.float32)
    winners = ok[order[first]]
    nearest[pixel[order[first]]] = winners
    depth[pixel[order[first]]] = z[winners]
    return nearest.reshape(h, w), depth.reshape(h, w)


def upsample(image: np.ndarray, frame: Frame) -> np.ndarray:
    step = DEPTH_DOWNSAMPLE
    return np.ascontiguousarray(image.repeat(step, 0).repeat(step, 1)[: frame.height, : frame.width])


def frame_labels(
    parts: Parts, part_task: np.ndarray, nearest: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(labels (h, w) int64 at the z-buffer resolution, task of each mask (M,)).

    A pixel shows the part of its nearest Gaussian. Segmenter granularity varies by frame: each
    blob is cut into halves with probability 0.3, and floor cells merge pairwise with
    probability 0.2, so primitives form at the finest cut any frame made, as with a real segmenter.
    """
    n_cells = parts.grid**2
    split = rng.uniform(size=N_BLOBS) < 0.3
    cell_target = np.arange(n_cells)
    merge = (rng.uniform(size=n_cells) < 0.2) & (cell_target % parts.grid % 2 == 1)
    cell_target[merge] -= 1
    # part ids: blobs 0..B-1, lower halves B..2B-1, floor cells 2B..2B+C-1
    part = np.where(
        parts.blob_of >= 0,
        parts.blob_of + N_BLOBS * (split[parts.blob_of] & parts.lower),
        2 * N_BLOBS + cell_target[np.maximum(parts.cell_of, 0)],
    )
    seen = np.where(nearest >= 0, part[np.maximum(nearest, 0)], -1)
    ids, area = np.unique(seen[seen >= 0], return_counts=True)
    kept = ids[area >= MIN_MASK_CELLS]
    lookup = np.full(2 * N_BLOBS + n_cells + 1, -1, dtype=np.int64)
    lookup[kept] = np.arange(len(kept))
    labels = lookup[seen]  # seen == -1 reads the last entry, which is -1
    return labels, part_task[kept]


def task_texts(n_tasks: int) -> list[str]:
    return [f"task {i:02d}: fetch the object of kind {i}" for i in range(n_tasks)]


def embedding_basis(n_tasks: int, rng: np.random.Generator) -> np.ndarray:
    """(T+1, D) orthonormal rows: a direction every embedding shares, then one per task."""
    return np.linalg.qr(rng.normal(size=(EMBED_DIM, n_tasks + 1)))[0].T


def text_embeddings(basis: np.ndarray) -> np.ndarray:
    """(T, D) unit task texts sqrt(MU0) c + sqrt(1 - MU0) r_t."""
    return np.sqrt(MU0) * basis[0] + np.sqrt(1 - MU0) * basis[1:]


def mask_embeddings(mask_task: np.ndarray, basis: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(M, D) unit embeddings whose cosines with the task texts are drawn from N(MU0, NOISE_STD),
    or N(MU1, NOISE_STD) for the mask's own task: built exactly from the wanted cosines plus a
    random component orthogonal to every text."""
    m, n_tasks = len(mask_task), basis.shape[0] - 1
    phi = MU0 + NOISE_STD * rng.standard_normal((m, n_tasks))
    relevant = mask_task >= 0
    phi[relevant, mask_task[relevant]] += MU1 - MU0
    along_tasks = (phi - MU0) / np.sqrt(1 - MU0)
    rest = rng.standard_normal((m, EMBED_DIM))
    rest -= (rest @ basis.T) @ basis
    rest /= np.linalg.norm(rest, axis=1, keepdims=True)
    rest_norm = np.sqrt(np.clip(1 - MU0 - (along_tasks**2).sum(axis=1), 0.0, None))
    emb = np.sqrt(MU0) * basis[0] + along_tasks @ basis[1:] + rest_norm[:, None] * rest
    return (emb / np.linalg.norm(emb, axis=1, keepdims=True)).astype(np.float32)


def setup(args: argparse.Namespace, work: Path) -> None:
    """Write the scene folder and the synthetic perception cache (run in a child process)."""
    rng = np.random.default_rng(args.seed)
    scene = work / "scene"
    (scene / "images").mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    grid = max(2, round(np.sqrt(args.masks)))
    gaussians, parts = make_gaussians(args.gaussians, grid, rng)
    write_ply(scene / "point_cloud.ply", gaussians)
    frames = make_frames(args.frames, args.width, args.height, scene / "images")
    basis = embedding_basis(args.tasks, rng)
    np.save(work / "texts.npy", text_embeddings(basis).astype(np.float32))
    # Each blob (both halves) is relevant to one task, about one blob in six to none; floor to none.
    blob_task = np.where(rng.uniform(size=N_BLOBS) < 1 / 6, NO_TASK, rng.integers(0, args.tasks, N_BLOBS))
    part_task = np.concatenate([blob_task, blob_task, np.full(grid**2, NO_TASK)])
    store = LocalStore(work / "cache")
    prefix = perception_prefix()
    for i, frame in enumerate(frames):
        nearest, depth = zbuffer(gaussians.means, frame)
        labels, mask_task = frame_labels(parts, part_task, nearest, rng)
        put_arrays(
            store,
            f"{prefix}{perception_input_digest(frame)}.npz",  # CacheKeys.perception_key's rule
            labels=upsample(labels, frame).astype(smallest_label_dtype(len(mask_task))),
            embeddings=mask_embeddings(mask_task, basis, rng),
        )
        if args.depth == "synthetic":
            frame.depth_path = scene / "depth" / f"frame_{i:05d}.npy"
            frame.depth_path.parent.mkdir(exist_ok=True)
            np.save(frame.depth_path, upsample(depth, frame))
    write_transforms(scene / "transforms.json", frames)
    (work / "setup.json").write_text(json.dumps({**vars(args), "setup_seconds": time.perf_counter() - t}))


# --------------------------------------------------------------------------------------------
# Stand-ins for the models (perception is not what this benchmark measures)
# --------------------------------------------------------------------------------------------
class FixedTextEncoder:
    """Returns the fixed embeddings of the benchmark's task strings (deterministic stand-in)."""

    model_id = "bench-fixed-text@000000000000"
    dim = EMBED_DIM

    def __init__(self, tasks: list[str], embeddings: np.ndarray) -> None:
        self._rows = {task: row for task, row in zip(tasks, embeddings, strict=True)}

    def encode_texts(self, texts: list[str]) -> np.ndarray:
        return np.stack([self._rows[t] for t in texts]).astype(np.float32)

    def encode_images(self, images: list[np.ndarray]) -> np.ndarray:
        raise RuntimeError("the scale benchmark reads a pre-written perception cache")


class BenchModels:
    """What fuse and cluster read of `Models`: the encoder, calibration (None = paper's values),
    the ids recorded in the result and the perception cache fingerprint."""

    fingerprint = FINGERPRINT
    profile_name = "bench"
    calibration = None
    device = None  # no forced device: fuse renders on the job's device, else on the CPU

    def __init__(self, encoder: FixedTextEncoder) -> None:
        self.encoder = encoder
        self.model_ids = {"profile": "bench", "encoder": encoder.model_id, "fingerprint": FINGERPRINT}


def perception_prefix() -> str:
    """The job's perception prefix for the stand-in models (the rule of `CacheKeys`)."""
    tmp = Path(tempfile.gettempdir())
    models = BenchModels(FixedTextEncoder(["x"], np.zeros((1, EMBED_DIM))))
    job = local_job(
        tmp,
        tmp,
        tmp,
        ["x"],
        PipelineParams(),
        models,  # type: ignore[arg-type]
        job_prefix="x/",
        cache_prefix=SCENE_PREFIX + "cache/",
    )
    return job.scene.keys.perception_prefix


# --------------------------------------------------------------------------------------------
# Measurement
# --------------------------------------------------------------------------------------------
def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def timed(fn: Any) -> tuple[Any, float, float]:
    wall, cpu = time.perf_counter(), cpu_seconds()
    out = fn()
    return out, time.perf_counter() - wall, cpu_seconds() - cpu


def output_params(args: argparse.Namespace) -> PipelineParams:
    """The pipeline's defaults, with depth from the synthetic files when asked; `--outputs arrays`
    turns the .ply exports and previews off (the result's arrays and summary only)."""
    extra = {"export_ply": False, "previews": False} if args.outputs == "arrays" else {}
    return PipelineParams(depth_source="input" if args.depth == "synthetic" else "median", **extra)


def bench_job(args: argparse.Namespace, work: Path, progress: ProgressFn = no_progress) -> Job:
    tasks = task_texts(args.tasks)
    encoder = FixedTextEncoder(tasks, np.load(work / "texts.npy", allow_pickle=False))
    return local_job(
        work / "scene",
        work / "job",
        work / "cache",
        tasks,
        output_params(args),
        BenchModels(encoder),  # type: ignore[arg-type]
        cache_prefix=SCENE_PREFIX + "cache/",
        progress=progress,
    )


def measure(args: argparse.Namespace, work: Path) -> None:
    shutil.rmtree(work / "job", ignore_errors=True)
    for stale in list((work / "cache").rglob("visibility")):  # fuse computes visibility afresh
        shutil.rmtree(stale)
    ticks: list[float] = []  # fuse reports progress once per frame: per-frame times for medians
    job = bench_job(
        args, work, lambda stage, fraction: ticks.append(time.perf_counter()) if stage == "fuse" else None
    )
    tasks = job.spec.tasks
    rss0 = peak_rss_mb()
    scene, load_s, _ = timed(lambda: job.scene.loaded)
    rss_load = peak_rss_mb()
    fuse_start = time.perf_counter()
    fuse, fuse_s, fuse_cpu = timed(lambda: run_stage("fuse", job, force=True))
    per_frame = np.diff([fuse_start, *ticks])
    rss_fuse = peak_rss_mb()
    cluster, cluster_s, cluster_cpu = timed(lambda: run_stage("cluster", job, force=True))
    rss_cluster = peak_rss_mb()

    n_frames = fuse["frames"]
    primitive_ids = read_result(job.spec.store, "result/").primitive_ids
    counts = cluster["counts"]
    print(
        f"scale benchmark: {len(scene.gaussians):,} Gaussians, {n_frames} frames at "
        f"{args.width}x{args.height}, {fuse['masks'] / n_frames:.0f} masks/frame, {len(tasks)} tasks, "
        f"depth={args.depth}"
    )
    print("  text encoder: deterministic stand-in (fixed embeddings; no CLIP); perception cache synthetic")
    print(
        f"  setup (child process, not measured below): {json.loads((work / 'setup.json').read_text())['setup_seconds']:.1f} s"
    )
    print(f"  load scene      {load_s:8.2f} s")
    print(
        f"  fuse            {fuse_s:8.2f} s  = {fuse_s / n_frames:.3f} s/frame "
        f"(CPU {fuse_cpu / n_frames:.3f} s/frame; aim < 0.5)  visibility computed for {fuse['frames_rendered']} frames, "
        f"masks {fuse['masks']:,}, rejected {fuse['masks_rejected']:,}"
    )
    print(
        f"    per frame: median {np.median(per_frame):.3f} s, p90 {np.percentile(per_frame, 90):.3f} s "
        f"(the first includes encoding the task texts)"
    )
    timings = cluster["timings"]
    print(
        f"  cluster         {cluster_s:8.2f} s  (CPU {cluster_cpu:.2f} s; aim < 2; outputs={args.outputs}; "
        f"without writing the result {cluster_s - sum(timings.get(k, 0.0) for k in WRITE_STEPS):.2f} s)"
    )
    print_steps([cluster])
    print(
        f"    AIB {timings['aib']:.3f} s on {counts['nodes_after_identical_merge']:,} nodes "
        f"({counts['primitives']:,} primitives; aim < 1 s on ~2,000)"
    )
    print("    counts: " + ", ".join(f"{k} {v:,}" for k, v in counts.items()))
    sizes = np.bincount(primitive_ids[primitive_ids >= 0])
    sizes = sizes[sizes > 0]
    print(
        f"    primitive sizes (Gaussians): median {np.median(sizes):.0f}, "
        f"{(sizes <= 10).sum():,} with <= 10, largest {sizes.max():,}"
    )
    print(
        f"  peak RSS MiB: start {rss0:.0f}, after load {rss_load:.0f}, after fuse {rss_fuse:.0f}, "
        f"after cluster {rss_cluster:.0f}"
    )


WRITE_STEPS = ("write", "exports", "previews")  # the cluster stage's steps that write the result


def print_steps(reports: list[dict[str, Any]]) -> None:
    """Per-step wall (and, where the report has them, process-CPU) seconds of cluster reports: the
    median over the runs, then each run's figure."""
    names = list(reports[0]["timings"])
    print(f"    {'step':<14}{'wall s':>8}{'CPU s':>8}   per run (wall)")
    for name in [*names, "total"]:
        if name == "total":
            walls = [r["seconds"] for r in reports]
            cpus = [sum(r.get("cpu_timings", {}).values()) for r in reports]
        else:
            walls = [r["timings"].get(name, 0.0) for r in reports]
            cpus = [r.get("cpu_timings", {}).get(name, float("nan")) for r in reports]
        runs = " ".join(f"{w:.2f}" for w in walls)
        print(f"    {name:<14}{np.median(walls):8.2f}{np.median(cpus):8.2f}   {runs}")
    optional = [sum(r["timings"].get(k, 0.0) for k in ("exports", "previews")) for r in reports]
    if max(optional) > 0:
        walls = [r["seconds"] - o for r, o in zip(reports, optional, strict=True)]
        cpus = [
            sum(v for k, v in r.get("cpu_timings", {}).items() if k not in ("exports", "previews"))
            for r in reports
        ]
        runs = " ".join(f"{w:.2f}" for w in walls)
        print(
            f"    {'w/o exports':<14}{np.median(walls):8.2f}{np.median(cpus):8.2f}   {runs}  (total - exports - previews)"
        )


def measure_cluster(args: argparse.Namespace, work: Path) -> None:
    """`--cluster-only`: rerun the cluster stage `--repeats` times on the fused state a previous
    `--keep` run left in the work folder; per-step medians."""
    job = bench_job(args, work)
    if not (work / "job").is_dir():
        raise SystemExit(f"{work}/job has no fused state: run once without --cluster-only, with --keep")
    _ = job.scene.loaded  # loading the scene is not the cluster stage's cost (it is cached per process)
    reports, walls, cpus = [], [], []
    for _ in range(args.repeats):
        report, wall, cpu = timed(lambda: run_stage("cluster", job, force=True))
        reports.append(report)
        walls.append(wall)
        cpus.append(cpu)
    counts = reports[-1]["counts"]
    print(
        f"cluster stage alone, {args.repeats} runs, outputs={args.outputs}: median wall {np.median(walls):.2f} s "
        f"(runs {' '.join(f'{w:.2f}' for w in walls)}), median process CPU {np.median(cpus):.2f} s"
    )
    print_steps(reports)
    print("    counts: " + ", ".join(f"{k} {v:,}" for k, v in counts.items()))
    ids = read_result(job.spec.store, "result/")
    digest = hashlib.sha256(np.ascontiguousarray(ids.object_ids, dtype=np.int64).tobytes()).hexdigest()[:16]
    chosen = [[o.object_id for o in ids.selections[t]] for t in job.spec.tasks]
    print(
        f"    partition digest {digest}; selections digest {hashlib.sha256(repr(chosen).encode()).hexdigest()[:16]}"
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--gaussians", type=int, default=400_000)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument(
        "--masks", type=int, default=100, help="floor cells (sqrt rounded, squared); ~100 masks/frame"
    )
    parser.add_argument("--tasks", type=int, default=26)
    parser.add_argument("--depth", choices=("synthetic", "render"), default="synthetic")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workdir", help="where the scene and caches go (default: a temp folder)")
    parser.add_argument("--keep", action="store_true", help="keep the work folder (reused when it matches)")
    parser.add_argument(
        "--outputs",
        choices=("full", "arrays"),
        default="full",
        help="full: the default result (arrays, .ply exports, previews); arrays: without exports/previews",
    )
    parser.add_argument(
        "--cluster-only",
        action="store_true",
        help="rerun only the cluster stage on a kept, fused work folder",
    )
    parser.add_argument("--repeats", type=int, default=3, help="cluster runs with --cluster-only (median)")
    parser.add_argument("--setup-only", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    work = Path(args.workdir or tempfile.mkdtemp(prefix="bfields-scale-"))
    if args.setup_only:
        setup(args, work)
        return
    local = ("workdir", "keep", "setup_only", "outputs", "cluster_only", "repeats")
    wanted = {k: v for k, v in vars(args).items() if k not in local}
    done = work / "setup.json"
    if not done.is_file() or {k: json.loads(done.read_text()).get(k) for k in wanted} != wanted:
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True)
        child = [sys.executable, __file__, "--setup-only", "--workdir", str(work)]
        child += [f"--{k}={v}" for k, v in wanted.items()]
        subprocess.run(child, check=True)
    try:
        (measure_cluster if args.cluster_only else measure)(args, work)
    finally:
        if not args.keep and not args.cluster_only:  # --cluster-only reuses the kept state: never delete it
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
