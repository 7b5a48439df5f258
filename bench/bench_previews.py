"""Benchmark the per-task preview renders of the cluster stage on the CPU (prints medians).

Renders every task's preview of a stored result over its scene (the scale bench's 400 k-Gaussian
scene: `python bench/bench_scale.py --setup-only` leaves one under --workdir) and prints the median
CPU and wall seconds per preview and the totals for all tasks, then the difference of the 8-bit
preview images (max and mean absolute difference, share of differing pixels) and of the chosen
views against a reference path:

- by default the reference is the renderer's default rasterisation constants (16-pixel tiles) at
  torch's default thread count, rendered in the same process (it skips the median-depth search,
  as previews now do, so it is a little cheaper than the code before);
- `--save DIR` writes each preview PNG to DIR and `--compare DIR` compares with PNGs saved by an
  earlier run, e.g. of an older checkout (PYTHONPATH=old/tree python bench/bench_previews.py
  --save DIR), which is how the figures before a change are reproduced.

Per-preview times include building the renderer (one per call here; the pipeline builds one for
all tasks, so `all tasks` is the stage's figure).
Usage: python bench/bench_previews.py [--scene /tmp/scale/scene --result /tmp/scale/job/result]
       [--max-side 480] [--tasks 26] [--no-reference] [--save DIR | --compare DIR]
"""

from __future__ import annotations

import argparse
import inspect
import io
import statistics
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from bayesian_fields_core.results import previews as pv
from bayesian_fields_core.results import read_result
from bayesian_fields_core.scene.loader import load_scene


def _timed(fn, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202 - thin timing wrapper
    c0, w0 = time.process_time(), time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.process_time() - c0, time.perf_counter() - w0


def _pixels(png: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)


def _diff(a: list[bytes], b: list[bytes]) -> str:
    """Max / mean absolute 8-bit difference and share of differing pixels over the previews."""
    worst, means, shares = 0, [], []
    for x, y in zip(a, b, strict=True):
        pa, pb = _pixels(x), _pixels(y)
        if pa.shape != pb.shape:
            return f"image sizes differ: {pa.shape} vs {pb.shape}"
        d = np.abs(pa - pb)
        worst = max(worst, int(d.max()))
        means.append(float(d.mean()))
        shares.append(float((d.max(-1) > 0).mean()))
    return (
        f"max abs diff {worst} (of 255), mean abs diff {statistics.mean(means):.4f} "
        f"(worst preview {max(means):.4f}), pixels differing {100 * statistics.mean(shares):.3f}% "
        f"(worst preview {100 * max(shares):.3f}%)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="/tmp/scale/scene")
    ap.add_argument("--result", default="/tmp/scale/job/result")
    ap.add_argument("--max-side", type=int, default=480)
    ap.add_argument("--tasks", type=int, default=0, help="first N tasks only (0: all)")
    ap.add_argument("--no-reference", action="store_true", help="skip the in-process reference path")
    ap.add_argument("--save", type=Path, help="write the previews' PNGs here")
    ap.add_argument("--compare", type=Path, help="compare with PNGs written by --save")
    ap.add_argument("--threads", type=int, default=0, help="torch intra-op threads (0: torch default)")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    print(
        f"torch {torch.__version__}, threads={torch.get_num_threads()}, code from {Path(pv.__file__).parent}"
    )

    scene = load_scene(args.scene)
    result = read_result(args.result)
    tasks = result.tasks[: args.tasks] if args.tasks else result.tasks
    result = replace(result, tasks=tasks)
    g, frames = scene.gaussians, scene.frames
    print(f"{len(g.means)} Gaussians, {len(frames)} frames, {len(tasks)} tasks, max side {args.max_side}")
    has_settings = "settings" in inspect.signature(pv.render_previews).parameters

    def run(
        settings: object | None, **extra: object
    ) -> tuple[list[pv.Preview], list[float], list[float], float, float]:
        if settings is not None:
            extra["settings"] = settings
        cpu, wall, out = [], [], []
        for task in tasks:
            one, c, w = _timed(pv.render_previews, replace(result, tasks=[task]), g, frames,
                               max_side=args.max_side, **extra)  # fmt: skip
            out += one
            cpu.append(c)
            wall.append(w)
        _, c_all, w_all = _timed(pv.render_previews, result, g, frames, max_side=args.max_side, **extra)
        return out, cpu, wall, c_all, w_all

    def report(label: str, cpu: list[float], wall: list[float], c_all: float, w_all: float) -> None:
        print(
            f"{label}: per preview median CPU {statistics.median(cpu):.3f} s, wall {statistics.median(wall):.3f} s "
            f"(min CPU {min(cpu):.3f}, max {max(cpu):.3f}); all {len(tasks)} tasks in one call: "
            f"CPU {c_all:.2f} s, wall {w_all:.2f} s",
            flush=True,
        )

    current, cpu, wall, c_all, w_all = run(None)
    report("current ", cpu, wall, c_all, w_all)
    if has_settings and not args.no_reference:
        from bayesian_fields_core.render.output import RasterSettings

        ref, cpu, wall, c_all, w_all = run(RasterSettings(), threads=None)
        report("reference (16-px tiles, torch's threads)", cpu, wall, c_all, w_all)
        same = sum(a.frame == b.frame for a, b in zip(current, ref, strict=True))
        print(
            f"vs reference: same view {same}/{len(tasks)}; {_diff([p.png for p in current], [p.png for p in ref])}"
        )
    if args.save:
        args.save.mkdir(parents=True, exist_ok=True)
        for i, p in enumerate(current):
            (args.save / f"task_{i:02d}.png").write_bytes(p.png)
            (args.save / f"task_{i:02d}.frame").write_text(str(p.frame))
    if args.compare:
        old = [(args.compare / f"task_{i:02d}.png").read_bytes() for i in range(len(current))]
        frames_old = [(args.compare / f"task_{i:02d}.frame").read_text() for i in range(len(current))]
        same = sum(str(p.frame) == f for p, f in zip(current, frames_old, strict=True))
        print(f"vs {args.compare}: same view {same}/{len(tasks)}; {_diff([p.png for p in current], old)}")


if __name__ == "__main__":
    main()
