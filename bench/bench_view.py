"""Start time and browser frame rate of `bfields view`, on the sample and on a 400k splat.

The 400k scene is the scale bench's generator (`bench_scale.make_gaussians`: a floor and 60 blobs)
with 30 orbit cameras; its result is synthetic but real in format: each blob is one object, five
tasks select five blobs each, written by `write_result` (no previews, so only the viewer is timed).
Start time = `load_view` (read the result, the splat and the cameras; cap; colours) + building the
viser scene and panel, to the moment the URL is served. Frame rate = requestAnimationFrame callbacks
per second in headless Debian chromium with SwiftShader (CPU WebGL, so a floor: a real GPU is far
faster), measured over 5 s after the splat has arrived. Usage:
  python bench/bench_view.py [--sample-run out/demo] [--gaussians 400000] [--no-browser]
"""

from __future__ import annotations

import argparse
import socket
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_scale import make_frames, make_gaussians  # noqa: E402

from bayesian_fields_core.geometry.obb import minimum_obb  # noqa: E402
from bayesian_fields_core.job.store import LocalStore  # noqa: E402
from bayesian_fields_core.results import Result, SelectedObject, write_result  # noqa: E402
from bayesian_fields_core.scene.nerfstudio import write_transforms  # noqa: E402
from bayesian_fields_core.scene.ply import write_ply  # noqa: E402

CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]  # fmt: skip


def big_run(n: int, work: Path) -> Path:
    rng = np.random.default_rng(0)
    scene = work / "scene"
    (scene / "images").mkdir(parents=True)
    gaussians, parts = make_gaussians(n, 10, rng)
    write_ply(scene / "point_cloud.ply", gaussians)
    write_transforms(scene / "transforms.json", make_frames(30, 640, 480, scene / "images"))
    ids = parts.blob_of.astype(np.int64)
    num_objects = int(ids.max()) + 1
    tasks = [f"task {t}" for t in range(5)]
    probs = rng.dirichlet(np.ones(len(tasks) + 1), num_objects).astype(np.float32)
    selections = {}
    for t, task in enumerate(tasks):
        chosen = []
        for obj in range(t * 5, t * 5 + 5):
            pts = gaussians.means[ids == obj]
            chosen.append(SelectedObject(obj, float(probs[obj, t]), len(pts), pts.mean(0), minimum_obb(pts)))
        selections[task] = chosen
    result = Result(tasks=tasks, object_ids=ids, probabilities=probs, selections=selections)
    run = work / "run"
    write_result(LocalStore(run), "result/", result, scene={"folder": str(scene.resolve())}, export_ply=False)
    return run


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def measure(run: Path, label: str, browser: bool) -> None:
    from bayesian_fields_core.viewer.data import load_view
    from bayesian_fields_core.viewer.server import ResultViewer

    t0 = time.perf_counter()
    data = load_view(run)
    t_load = time.perf_counter() - t0
    viewer = ResultViewer(data, port=_port())
    t_start = time.perf_counter() - t0
    t = time.perf_counter()
    viewer.select_task(data.tasks[-1])
    t_switch = time.perf_counter() - t
    line = (f"{label}: {len(data.kept):,} Gaussians; start {t_start:.2f} s (load {t_load:.2f} s); "
            f"task switch {t_switch * 1000:.0f} ms")  # fmt: skip
    if browser and Path("/usr/bin/chromium").is_file():
        from playwright.sync_api import sync_playwright

        with sync_playwright() as pw:
            b = pw.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
            page = b.new_page(viewport={"width": 1280, "height": 720})
            t = time.perf_counter()
            page.goto(viewer.url)
            page.wait_for_selector("canvas", state="attached", timeout=120_000)
            t_page = time.perf_counter() - t
            page.wait_for_timeout(3000)
            fps = page.evaluate(
                "() => new Promise(r => { let n = 0; const t0 = performance.now();"
                " const f = () => { n++; if (performance.now() - t0 < 5000) requestAnimationFrame(f);"
                " else r(n * 1000 / (performance.now() - t0)); }; requestAnimationFrame(f); })"
            )
            line += f"; page up {t_page:.1f} s; {fps:.1f} frames/s (SwiftShader)"
            b.close()
    viewer.stop()
    print(line, flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sample-run", help="a `bfields run samples/tabletop --out DIR` folder")
    parser.add_argument("--gaussians", type=int, default=400_000)
    parser.add_argument("--no-browser", action="store_true")
    args = parser.parse_args()
    if args.sample_run:
        measure(Path(args.sample_run), "sample", not args.no_browser)
    if args.gaussians:
        with tempfile.TemporaryDirectory(prefix="bf-bench-view-") as tmp:
            t = time.perf_counter()
            run = big_run(args.gaussians, Path(tmp))
            print(f"generated {args.gaussians:,}-Gaussian scene + result in {time.perf_counter() - t:.1f} s")
            measure(run, f"{args.gaussians // 1000}k", not args.no_browser)


if __name__ == "__main__":
    main()
