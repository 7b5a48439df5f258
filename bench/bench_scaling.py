"""Scaling curve of the real `fuse` and `cluster` stages: Gaussians x tasks x frames, on the CPU.

Grid (issue 11, item 6): 100k, 400k, 1M, 5M Gaussians x 26 and 100 tasks x 300 and 1000 frames.
Each point reports fuse seconds per frame (median over frames), cluster seconds, the fusion
state's bytes and the peak RSS of each stage (each stage runs in its own child process, so a peak
is that stage's own: scene load + the stage).

The scene and perception are bench_scale.py's (same generator, ideal segmenter over z-buffered
Gaussian centres, ~100 masks/frame, paper-calibrated synthetic embeddings, fixed task texts,
depth from the same z-buffer with `depth_source='input'`, so no rendering is timed). One scene
per Gaussian count serves both task counts (same labels; embeddings and task texts per count).

What is measured and what is extrapolated (the output says which, per row):
- fuse is linear in frames (one projection + depth test + scatter-add per frame, nothing carried
  but the (N, T) state): every point fuses `--fuse-frames` frames and, where the scene was set up
  with more (`--max-setup-frames`, per size), all of them too, which shows the per-frame time does
  not change with the frame count; 300 and 1000 frames are that per-frame median multiplied out
  (marked "extrapolated" where fewer frames were fused);
- cluster runs after each fuse, on that fuse's state and frames (measured as it stands; the
  README's scaling section says how it grows with frames);
- results preview images are off (`previews=False`, `export_ply=False`): they render the scene
  once per task and are not part of the algorithm's scaling.

Usage:
  python bench/bench_scaling.py [--sizes 100000,400000,1000000,5000000] [--tasks 26,100]
      [--fuse-frames 20] [--max-setup-frames 300:100000=1000,5000000=60] [--workdir DIR]
      [--child-timeout 1200] [--json OUT]
Every child runs under a timeout; a point that does not finish is reported as such.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_scale as bs  # noqa: E402 - sibling benchmark module, not a package

from bayesian_fields_core.job.artifacts import FUSION_KEY  # noqa: E402
from bayesian_fields_core.job.content_keys import perception_input_digest  # noqa: E402
from bayesian_fields_core.job.factories import Job, local_job  # noqa: E402
from bayesian_fields_core.job.pipeline import run_stage  # noqa: E402
from bayesian_fields_core.job.runner import ProgressFn  # noqa: E402
from bayesian_fields_core.job.store import LocalStore, put_arrays  # noqa: E402
from bayesian_fields_core.params import PipelineParams  # noqa: E402
from bayesian_fields_core.scene.nerfstudio import write_transforms  # noqa: E402
from bayesian_fields_core.scene.ply import write_ply  # noqa: E402
from bayesian_fields_core.stages.perceive import smallest_label_dtype  # noqa: E402

WIDTH, HEIGHT, MASKS = 640, 480, 100


# --------------------------------------------------------------------------------------------
# Setup: one scene per Gaussian count, one perception cache per task count
# --------------------------------------------------------------------------------------------
def setup(work: Path, n_gaussians: int, n_frames: int, task_counts: list[int], seed: int) -> dict:
    """Scene folder (ply, transforms, depth) and a perception cache `cache-T/` per task count."""
    done = work / "setup.json"
    want = {"gaussians": n_gaussians, "frames": n_frames, "tasks": task_counts, "seed": seed}
    if done.is_file():
        record = json.loads(done.read_text())
        if {k: record.get(k) for k in want} == want:
            return record
    shutil.rmtree(work, ignore_errors=True)
    (work / "scene" / "images").mkdir(parents=True)
    (work / "scene" / "depth").mkdir()
    t = time.perf_counter()
    rng = np.random.default_rng(seed)
    grid = max(2, round(np.sqrt(MASKS)))
    gaussians, parts = bs.make_gaussians(n_gaussians, grid, rng)
    write_ply(work / "scene" / "point_cloud.ply", gaussians)
    frames = bs.make_frames(n_frames, WIDTH, HEIGHT, work / "scene" / "images")
    n_parts = 2 * bs.N_BLOBS + grid**2
    per_tasks = {}
    for n_tasks in task_counts:
        trng = np.random.default_rng([seed, n_tasks])
        basis = bs.embedding_basis(n_tasks, trng)
        np.save(work / f"texts-{n_tasks}.npy", bs.text_embeddings(basis).astype(np.float32))
        blob_task = np.where(
            trng.uniform(size=bs.N_BLOBS) < 1 / 6, bs.NO_TASK, trng.integers(0, n_tasks, bs.N_BLOBS)
        )
        part_task = np.concatenate([blob_task, blob_task, np.full(grid**2, bs.NO_TASK)])
        per_tasks[n_tasks] = (trng, basis, part_task, LocalStore(work / f"cache-{n_tasks}"))
    prefix = bs.perception_prefix()
    for i, frame in enumerate(frames):
        nearest, depth = bs.zbuffer(gaussians.means, frame)
        # part_task = identity: frame_labels then returns the kept parts, mapped per task count below
        labels, kept = bs.frame_labels(parts, np.arange(n_parts), nearest, rng)
        full = bs.upsample(labels, frame).astype(smallest_label_dtype(len(kept)))
        for trng, basis, part_task, store in per_tasks.values():
            put_arrays(
                store,
                f"{prefix}{perception_input_digest(frame)}.npz",
                labels=full,
                embeddings=bs.mask_embeddings(part_task[kept], basis, trng),
            )
        frame.depth_path = work / "scene" / "depth" / f"frame_{i:05d}.npy"
        np.save(frame.depth_path, bs.upsample(depth, frame))
    write_transforms(work / "scene" / "transforms.json", frames)
    record = {**want, "setup_seconds": time.perf_counter() - t}
    done.write_text(json.dumps(record))
    return record


# --------------------------------------------------------------------------------------------
# One stage in a child process (its own peak RSS)
# --------------------------------------------------------------------------------------------
def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def bench_job(work: Path, job: Path, n_tasks: int, n_frames: int, progress: ProgressFn) -> Job:
    tasks = bs.task_texts(n_tasks)
    encoder = bs.FixedTextEncoder(tasks, np.load(work / f"texts-{n_tasks}.npy", allow_pickle=False))
    params = PipelineParams(
        depth_source="input", export_ply=False, previews=False, max_frames=n_frames, fusion_backend="cpu"
    )
    return local_job(
        work / "scene",
        job,
        work / f"cache-{n_tasks}",
        tasks,
        params,
        bs.BenchModels(encoder),  # type: ignore[arg-type]
        cache_prefix=bs.SCENE_PREFIX + "cache/",
        progress=progress,
    )


def child(work: Path, job: Path, stage: str, n_tasks: int, n_frames: int) -> dict:
    """Run one stage; return its figures (printed as JSON by the child)."""
    ticks: list[tuple[float, float]] = []  # (wall, process CPU) at each progress tick of the stage
    bench = bench_job(
        work,
        job,
        n_tasks,
        n_frames,
        lambda name, fraction: ticks.append((time.perf_counter(), cpu_seconds())) if name == stage else None,
    )
    if stage == "fuse":  # visibility computed afresh, as on a scene's first run
        for stale in list((work / f"cache-{n_tasks}").rglob("visibility")):
            shutil.rmtree(stale)
    scene = bench.scene.loaded
    rss_load = peak_rss_mib()
    cpu0, t0 = cpu_seconds(), time.perf_counter()
    report = run_stage(stage, bench, force=True)
    wall, cpu = time.perf_counter() - t0, cpu_seconds() - cpu0
    out = {
        "stage": stage,
        "gaussians": len(scene.gaussians),
        "tasks": n_tasks,
        "frames": n_frames,
        "wall_s": wall,
        "cpu_s": cpu,
        "rss_load_mib": rss_load,
        "rss_peak_mib": peak_rss_mib(),
    }
    if stage == "fuse":
        # wall and CPU per frame: on a shared machine the CPU seconds are the figure that load
        # does not inflate (fusion is single-threaded numpy, so CPU ~ wall on an idle machine)
        walls = np.diff([t0, *(w for w, _ in ticks)])
        cpus = np.diff([cpu0, *(c for _, c in ticks)])
        skip = 1 if len(walls) > 2 else 0  # the first frame warms up (imports, allocation)
        out["s_per_frame_median"] = float(np.median(walls[skip:]))
        out["cpu_per_frame_median"] = float(np.median(cpus[skip:]))
        out["masks_per_frame"] = report["masks"] / report["frames"]
        out["state_bytes"] = len(scene.gaussians) * n_tasks * 4
        out["artifact_bytes"] = (job / FUSION_KEY).stat().st_size
    else:
        out["timings"] = report["timings"]
        out["primitives"] = report["counts"].get("primitives")
        out["aib_nodes"] = report["counts"].get("nodes_after_identical_merge")
    return out


def run_child(
    args: argparse.Namespace, work: Path, job: Path, stage: str, n_tasks: int, n_frames: int
) -> dict:
    cmd = [sys.executable, __file__, "--child", stage, "--workdir", str(work), "--job", str(job)]
    cmd += ["--child-tasks", str(n_tasks), "--child-frames", str(n_frames)]
    t = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=args.child_timeout)
    except subprocess.TimeoutExpired:
        return {"stage": stage, "error": f"timed out after {args.child_timeout} s"}
    if proc.returncode != 0:
        return {
            "stage": stage,
            "error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "failed",
        }
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["child_wall_s"] = time.perf_counter() - t
    return out


# --------------------------------------------------------------------------------------------
# The grid
# --------------------------------------------------------------------------------------------
def parse_caps(text: str) -> tuple[int, dict[int, int]]:
    """'300:100000=1000,5000000=60' -> (default 300, {100000: 1000, 5000000: 60})."""
    default, _, rest = text.partition(":")
    caps = {}
    for item in filter(None, rest.split(",")):
        size, _, frames = item.partition("=")
        caps[int(size)] = int(frames)
    return int(default), caps


def fmt_mib(x: float) -> str:
    return f"{x / 1024:.2f} GiB" if x >= 1024 else f"{x:.0f} MiB"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="100000,400000,1000000,5000000")
    parser.add_argument("--tasks", default="26,100")
    parser.add_argument("--frames", default="300,1000", help="frame counts of the table")
    parser.add_argument("--fuse-frames", type=int, default=20, help="frames fused per point for s/frame")
    parser.add_argument(
        "--max-setup-frames",
        default="300:100000=1000,5000000=60",
        help="frames set up per size: default[:size=frames,...]; cluster runs on all of them",
    )
    parser.add_argument("--no-cluster", action="store_true", help="fuse only")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/bfields-scaling"))
    parser.add_argument("--child-timeout", type=float, default=1200)
    parser.add_argument("--json", type=Path, help="append each point's figures here (JSON lines)")
    parser.add_argument("--child", choices=("fuse", "cluster"), help=argparse.SUPPRESS)
    parser.add_argument("--job", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--child-tasks", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--child-frames", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.workdir, args.job, args.child, args.child_tasks, args.child_frames)))
        return 0

    sizes = [int(s) for s in args.sizes.split(",")]
    task_counts = [int(t) for t in args.tasks.split(",")]
    table_frames = [int(f) for f in args.frames.split(",")]
    default_frames, caps = parse_caps(args.max_setup_frames)
    print(
        f"scaling bench: {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f} at start; fuse s/frame from "
        f"{args.fuse_frames} frames (median after the first); depth_source=input, numpy fusion, no previews"
    )

    def record(point: dict) -> None:
        if args.json:
            with args.json.open("a") as fh:
                fh.write(json.dumps(point) + "\n")

    for size in sizes:
        n_setup = caps.get(size, default_frames)
        work = args.workdir / f"g{size}"
        t = time.perf_counter()
        rec = setup(work, size, n_setup, task_counts, args.seed)
        print(
            f"{size:,} Gaussians: scene + perception for {n_setup} frames x {task_counts} tasks "
            f"({rec['setup_seconds']:.0f} s to generate; {time.perf_counter() - t:.0f} s now)",
            flush=True,
        )
        for n_tasks in task_counts:
            job = work / f"job-{n_tasks}"
            # fuse then cluster at the short frame count and, when the scene has more, at all of them
            for n_frames in sorted({min(args.fuse_frames, n_setup), n_setup}):
                fuse = run_child(args, work, job, "fuse", n_tasks, n_frames)
                record(fuse)
                if "error" in fuse:
                    cluster = {"error": "no fused state"}
                elif args.no_cluster:
                    cluster = {"error": "not run (--no-cluster)"}
                else:
                    cluster = run_child(args, work, job, "cluster", n_tasks, n_frames)
                record(cluster)
                print_point(size, n_tasks, fuse, cluster, table_frames)
    print(f"load {os.getloadavg()[0]:.2f} at end")
    return 0


def print_point(size: int, n_tasks: int, fuse: dict, cluster: dict, table_frames: list[int]) -> None:
    if "error" in fuse:
        print(f"  {size:,} x {n_tasks} tasks: fuse {fuse['error']}", flush=True)
        return
    spf, n = fuse["s_per_frame_median"], fuse["frames"]
    cpf = fuse.get("cpu_per_frame_median", fuse["cpu_s"] / n)
    print(
        f"  {size:,} x {n_tasks} tasks, {n} frames: fuse {fuse['wall_s']:.1f} s (CPU {fuse['cpu_s']:.1f} s), "
        f"{spf:.3f} s/frame median (CPU {cpf:.3f} s/frame median), "
        f"{fuse['masks_per_frame']:.0f} masks/frame; state {fuse['state_bytes'] / 2**20:.0f} MiB, "
        f"artifact {fuse['artifact_bytes'] / 2**20:.0f} MiB; peak RSS {fmt_mib(fuse['rss_peak_mib'])} "
        f"(scene loaded {fmt_mib(fuse['rss_load_mib'])})",
        flush=True,
    )
    if "error" in cluster:
        print(f"    cluster: {cluster['error']}", flush=True)
    else:
        timings = ", ".join(f"{k} {v:.2f}" for k, v in cluster["timings"].items())
        print(
            f"    cluster: {cluster['wall_s']:.2f} s (CPU {cluster['cpu_s']:.2f} s; {timings}); "
            f"{cluster['primitives']:,} primitives, {cluster['aib_nodes']:,} AIB nodes; "
            f"peak RSS {fmt_mib(cluster['rss_peak_mib'])}",
            flush=True,
        )
    for frames in table_frames:
        # the stage's fixed part (texts, final write) once, plus the per-frame median for the rest;
        # wall as measured (inflated by the machine's load) and CPU seconds (what load does not inflate)
        total = fuse["wall_s"] + spf * (frames - n)
        total_cpu = fuse["cpu_s"] + cpf * (frames - n)
        kind = "measured" if frames == n else f"extrapolated from {n} frames"
        print(f"    {frames} frames: fuse {total:.0f} s wall, {total_cpu:.0f} s CPU ({kind})", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
