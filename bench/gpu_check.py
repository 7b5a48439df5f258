"""Per-stage figures of the scale scene on one device: render, fuse, perceive, cluster, total;
and the fidelity of our torch rasteriser against gsplat on the same splat and cameras.

Run by bench/gpu_check.sh (which installs what it needs and builds the reference models). On a
GPU: gsplat renders (median depth from its own traversal), fusion runs as torch ops on the GPU,
perception uses the reference FastSAM-x (fp16, imgsz 1024) and CLIP ViT-B/16 (fp16) on frames
rendered from the scene, crops batched across frames. Then `--fidelity-frames` frames are rendered
by our torch rasteriser and by gsplat, and RGB PSNR, expected / median depth agreement, the
Jaccard of the (Gaussian, mask) associations and the agreement of the fused log-odds are printed
(gpu_check_fidelity.py). With --cpu the same code runs at a smoke size on the CPU, so a typo
costs no GPU time; gsplat cannot run there, so the comparison says it is skipped and runs with our
renderer on both sides (which must agree perfectly), exercising its code.

What is real: the scene folder, the renderer, the fuse and cluster stages (`run_stage`), the
perceive stage with the reference architectures (random weights). What is synthetic: the
perception cache that fuse/cluster read for the full frame count (bench_scale.py's ideal
segmenter, so the cluster stage sees realistic masks) and the task-text embeddings.
Usage: python bench/gpu_check.py --models DIR [--cpu] [--gaussians N] [--frames F] [--fidelity-frames F]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch
import yaml
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_scale  # noqa: E402 - sibling benchmark module, not a package
import gpu_check_fidelity  # noqa: E402 - sibling module, not a package

from bayesian_fields_core.fusion.state import FusionSettings  # noqa: E402
from bayesian_fields_core.job.factories import Job, local_job  # noqa: E402
from bayesian_fields_core.job.pipeline import run_stage  # noqa: E402
from bayesian_fields_core.params import PipelineParams  # noqa: E402
from bayesian_fields_core.perception.models import load_models  # noqa: E402
from bayesian_fields_core.render import GaussianRenderer  # noqa: E402
from bayesian_fields_core.scene.loader import load_scene  # noqa: E402
from bayesian_fields_core.stages.fuse import frame_scores, likelihood_params  # noqa: E402


def sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def render_frames(scene, device: str, n: int, n_images: int, image_of) -> tuple[float, str]:  # noqa: ANN001
    """Median ms/frame of a depth-only render (expected + median depth) on `device` over `n`
    frames; the first `n_images` frames also get their colour render written to `image_of(frame)`
    (the perceive scene's copy: the fuse scene's images key its synthetic perception cache)."""
    renderer = GaussianRenderer(scene.gaussians, device=device)
    times = []

    def write_image(frame) -> None:  # noqa: ANN001
        rgb = renderer.render(frame.K, frame.world_to_camera, frame.width, frame.height).rgb
        target = image_of(frame)
        target.unlink(missing_ok=True)  # a hard link to the fuse scene's image: never write through it
        Image.fromarray((np.clip(rgb, 0, 1) * 255).astype(np.uint8)).save(target)

    for i, frame in enumerate(scene.frames[: max(n, n_images)]):
        if i >= n:  # only an image is wanted from this frame
            write_image(frame)
            continue
        images = i < n_images
        sync(device)
        t = time.perf_counter()
        renderer.render_tensors(frame.K, frame.world_to_camera, frame.width, frame.height, depth_only=True)
        sync(device)
        times.append(time.perf_counter() - t)
        if images:  # real pictures for the perceive stage: the scene's own colour render
            write_image(frame)
    skip = 1 if len(times) > 2 else 0  # the first call pays kernel compilation / warm-up
    return 1000 * float(np.median(times[skip:])), renderer.backend


def reference_profile(models: Path, gpu: bool, device: str) -> dict:
    """The reference FastSAM + HF CLIP profile; on a GPU at fp16 and FastSAM's paper imgsz."""
    prof = yaml.safe_load((models / "profiles" / "reference-fastsam-hf-clip.yaml").read_text())
    base = models / "profiles"
    prof["segmenter"]["params"]["weights"] = str((base / prof["segmenter"]["params"]["weights"]).resolve())
    prof["encoder"]["path"] = str((base / prof["encoder"]["path"]).resolve())
    prof["segmenter"]["params"]["device"] = device
    prof["encoder"]["device"] = device
    if gpu:
        prof["segmenter"]["params"].update(half=True, imgsz=1024)
        prof["encoder"]["params"]["dtype"] = "float16"
    else:
        prof["segmenter"]["params"].update(imgsz=320)
    return prof


def renderer_fidelity(job: Job, scene, device: str, gpu: bool, n: int) -> dict:  # noqa: ANN001
    """Our torch rasteriser against gsplat on the first `n` frames of the fuse job (its masks and
    scores); on the CPU, our rasteriser on both sides. Prints the figures and returns them."""
    ours = GaussianRenderer(scene.gaussians, device=device, backend="torch")
    if gpu:
        other = GaussianRenderer(scene.gaussians, device=device, backend="gsplat")
        print(f"  fidelity: torch rasteriser vs gsplat, {n} frames (reference: torch)")
    else:
        other = ours
        print(f"  fidelity: gsplat comparison skipped (no CUDA in the CPU smoke); the comparison ran with "
              f"the torch rasteriser on both sides, {n} frames (must agree exactly)")  # fmt: skip
    spec, job_scene, models = job.spec, job.scene, job.runner.models
    p = spec.params
    text = models.encoder.encode_texts(list(spec.tasks)).astype(np.float32)
    settings = FusionSettings(
        likelihood_params(p, models), "bayes", p.prior, p.outlier_rejection, p.view_correlation
    )
    t = time.perf_counter()
    fid = gpu_check_fidelity.compare_renderers(
        list(job_scene.selected_frames[:n]),
        ours,
        other,
        scene.gaussians.means,
        lambda index: frame_scores(spec, job_scene, index, text),
        settings,
        num_tasks=len(spec.tasks),
        # the run's lengths in scene units, as the fuse stage passes them (fractions of the scale)
        depth_tolerance=job_scene.lengths.depth_tolerance,
        relative_tolerance=p.depth_tolerance_relative,
        near=job_scene.lengths.visibility_near,
        device=device,
    )
    for line in gpu_check_fidelity.report_lines(fid):
        print(line)
    print(f"  fidelity took {time.perf_counter() - t:.1f} s")
    return {"compared_with": "gsplat" if gpu else "torch (smoke)", **fid.as_dict()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", type=Path, required=True, help="make_reference_models.py output")
    parser.add_argument("--cpu", action="store_true", help="smoke mode: CPU, small scene")
    parser.add_argument("--gaussians", type=int)
    parser.add_argument("--frames", type=int)
    parser.add_argument("--perceive-frames", type=int)
    parser.add_argument("--fidelity-frames", type=int, help="frames rendered by both rasterisers")
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/bfields-gpu-check"))
    args = parser.parse_args(argv)
    gpu = not args.cpu
    if gpu and not torch.cuda.is_available():
        print("no CUDA device: run with --cpu for the smoke test", file=sys.stderr)
        return 2
    device = "cuda" if gpu else "cpu"
    if not gpu:
        # Many small torch ops per frame: on a shared CPU, OpenMP threads spinning at barriers
        # cost far more than they gain (the renderer tests run single-threaded for this reason).
        torch.set_num_threads(1)
    n_g = args.gaussians or (400_000 if gpu else 20_000)
    n_f = args.frames or (300 if gpu else 6)
    n_p = args.perceive_frames or (20 if gpu else 2)
    width, height = (640, 480) if gpu else (160, 120)
    work = args.workdir
    setup = argparse.Namespace(
        gaussians=n_g, frames=n_f, width=width, height=height, masks=100, tasks=26, depth="render", seed=0
    )
    t = time.perf_counter()
    if work.exists():
        shutil.rmtree(work)
    bench_scale.setup(setup, work)  # scene folder + synthetic perception cache for n_f frames
    print(f"gpu_check ({'GPU ' + torch.cuda.get_device_name() if gpu else 'CPU smoke'}): {n_g:,} Gaussians, "
          f"{n_f} frames at {width}x{height}, 26 tasks; setup {time.perf_counter() - t:.1f} s")  # fmt: skip
    scene = load_scene(work / "scene")

    # The perceive stage reads a copy of the scene (hard links) whose images are the splat's own
    # colour render; the fuse scene keeps the images its synthetic perception cache is keyed by.
    perceive_scene = work / "perceive-scene"
    shutil.copytree(work / "scene", perceive_scene, copy_function=os.link)

    def perceive_image(frame) -> Path:  # noqa: ANN001
        return perceive_scene / frame.image_path.resolve().relative_to((work / "scene").resolve())

    render_ms, backend = render_frames(
        scene,
        device,
        min(n_f, 10 if gpu else 3),
        n_images=n_f,  # every frame: the stage's alignment check samples frames across the scene
        image_of=perceive_image,
    )
    print(f"  render   {render_ms:9.1f} ms/frame  (backend {backend}, depth + median depth)")

    tasks = bench_scale.task_texts(26)
    encoder = bench_scale.FixedTextEncoder(tasks, np.load(work / "texts.npy", allow_pickle=False))
    job = local_job(
        work / "scene",
        work / "job",
        work / "cache",
        tasks,
        PipelineParams(export_ply=False, device=device),
        bench_scale.BenchModels(encoder),  # type: ignore[arg-type]
        cache_prefix=bench_scale.SCENE_PREFIX + "cache/",
    )
    sync(device)
    t = time.perf_counter()
    fuse = run_stage("fuse", job, force=True)
    sync(device)
    fuse_s = time.perf_counter() - t
    print(f"  fuse     {1000 * fuse_s / n_f:9.1f} ms/frame  (render + associations + update; "
          f"fusion on {fuse['fusion_device']}, {fuse['masks'] / n_f:.0f} masks/frame)")  # fmt: skip
    t = time.perf_counter()
    cluster = run_stage("cluster", job, force=True)
    cluster_s = time.perf_counter() - t
    print(f"  cluster  {cluster_s:9.2f} s        ({cluster['counts']['primitives']:,} primitives)")

    fidelity = renderer_fidelity(job, scene, device, gpu, args.fidelity_frames or (10 if gpu else 2))

    prof = reference_profile(args.models, gpu, device)
    models = load_models(prof)
    perceive_job = local_job(
        perceive_scene,
        work / "pjob",
        work / "pcache",
        tasks[:1],
        PipelineParams(max_frames=n_p, device=device),
        models,
        cache_prefix="scenes/perceive/cache/",
    )
    _ = models.segmenter, models.encoder  # load outside the timing
    warm = np.asarray(Image.open(perceive_image(scene.frames[0])).convert("RGB"))
    models.segmenter.segment(warm)
    t = time.perf_counter()
    perceive = run_stage("perceive", perceive_job, force=True)
    perceive_s = time.perf_counter() - t
    per_frame = 1000 * perceive_s / n_p
    print(f"  perceive {per_frame:9.1f} ms/frame  (FastSAM + ViT-B/16 {'fp16' if gpu else 'fp32'}, "
          f"{perceive['masks_computed'] / n_p:.0f} masks/frame, {perceive['encoder_calls']} encoder calls; "
          f"segment {perceive['segment_seconds']:.2f} s, embed {perceive['embed_seconds']:.2f} s over {n_p} frames)")  # fmt: skip
    total = (perceive_s / n_p + fuse_s / n_f) * n_f + cluster_s
    print(f"  total    {total:9.1f} s for {n_f} frames (perceive and fuse per frame x frames + cluster)")
    (work / "gpu_check.json").write_text(
        json.dumps(
            {
                "render_ms": render_ms,
                "fuse_ms": 1000 * fuse_s / n_f,
                "perceive_ms": per_frame,
                "cluster_s": cluster_s,
                "total_s": total,
                "device": device,
                "backend": backend,
                "fidelity": fidelity,
            }
        )  # fmt: skip
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
