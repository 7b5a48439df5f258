"""The alignment check's numbers on a good scene and on misaligned copies of it (CPU).

Builds, from a scene folder (default samples/tabletop), the copies the thresholds of
`checks/alignment.py` were chosen on: as shipped; photos degraded like a real capture against its
splat (blur, a few pixels of shift, noise, gamma, gain); splat scaled 0.5 + shifted 0.4 m; shifted 0.4 m; scaled 0.5;
rotated 20 degrees about z; cameras with the OpenGL/OpenCV convention flipped; photos shuffled
between cameras; splat shifted 10 m. Prints, per copy, the geometric shares, the extent ratio,
the rendered score (median ZNCC), coverage, the verdict and the seconds (median of --repeats).
Usage: python bench/bench_alignment.py [--scene samples/tabletop] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from PIL import Image
from scipy import ndimage

from bayesian_fields_core.checks.alignment import assess_alignment, geometric_alignment
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.scene.loader import load_scene
from tests.support.scene_transforms import (
    copy_scene,
    flip_camera_convention,
    move_splat,
    rotation_z,
    shuffle_images,
)


def degrade_photos(folder: Path, blur: float = 3.0, shift: int = 2) -> Path:
    """Blur, a shift of a few pixels (pose error), gamma 0.8, gain 1.2 and noise (std 0.05): a
    real splat never reproduces its photos pixel for pixel."""
    rng = np.random.default_rng(0)
    for path in sorted((folder / "images").iterdir()):
        img = np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255.0
        img = np.roll(ndimage.gaussian_filter(img, (blur, blur, 0.0)), (shift, shift), axis=(0, 1))
        img = np.clip(1.2 * img**0.8 + rng.normal(0.0, 0.05, img.shape), 0.0, 1.0)
        Image.fromarray((img * 255).astype(np.uint8)).save(path)
    return folder


VARIANTS: dict[str, Callable[[Path], Path]] = {
    "as shipped": lambda f: f,
    "degraded (blur 3, shift 2)": degrade_photos,
    "degraded (blur 4, shift 4)": lambda f: degrade_photos(f, 4.0, 4),
    "scaled 0.5 + shifted 0.4 m": lambda f: move_splat(f, scale=0.5, shift=(0.4, 0.0, 0.0)),
    "shifted 0.4 m": lambda f: move_splat(f, shift=(0.4, 0.0, 0.0)),
    "scaled 0.5": lambda f: move_splat(f, scale=0.5),
    "rotated 20 deg": lambda f: move_splat(f, rotation=rotation_z(20.0)),
    "OpenGL/OpenCV flipped": flip_camera_convention,
    "images shuffled": shuffle_images,
    "shifted 10 m": lambda f: move_splat(f, shift=(10.0, 0.0, 0.0)),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="samples/tabletop")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    params = PipelineParams()
    print(
        f"{'scene':28s} {'frustum':>7s} {'flipped':>7s} {'extent':>6s} {'score':>6s} {'cover':>5s}  verdict"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for i, (name, make) in enumerate(VARIANTS.items()):
            folder = make(copy_scene(Path(args.scene), Path(tmp) / f"v{i}"))
            scene = load_scene(folder)
            times, geo_times = [], []
            for _ in range(args.repeats):
                t = time.perf_counter()
                geometric_alignment(scene)
                geo_times.append(time.perf_counter() - t)
                t = time.perf_counter()
                report = assess_alignment(scene, params)
                times.append(time.perf_counter() - t)
            g, r = report.geometry, report.rendered
            score = f"{r.score:6.2f}" if r else "     -"
            cover = f"{r.coverage:5.2f}" if r else "    -"
            ratio = f"{g.extent_ratio:6.2f}" if g.extent_ratio is not None else "     -"
            verdict = "pass" if report.passed else f"REFUSED: {report.cause}"
            print(
                f"{name:28s} {g.frustum_share:7.2f} {g.flipped_frustum_share:7.2f} {ratio} {score} {cover}  "
                f"[geometry {statistics.median(geo_times):.3f} s, all {statistics.median(times):.2f} s] {verdict}"
            )


if __name__ == "__main__":
    main()
