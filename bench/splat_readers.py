"""Reader speed: our INRIA PLY reader (`scene.ply.read_ply`, header checks, finite and sanity
checks, SH re-layout included) against gsply's `plyread` (raw arrays, no checks) on one large
synthetic SH-degree-3 splat, warm page cache. Run by hand:

    python bench/splat_readers.py --gigabytes 1 --repeats 3 [--dir /tmp]

gsply is not a dependency: `pip install gsply` to include it. Prints medians and MB/s.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from bayesian_fields_core.scene.ply import read_ply, write_ply
from bayesian_fields_core.scene.types import Gaussians

ROW_BYTES = 4 * (3 + 3 + 3 + 45 + 1 + 3 + 4)  # x y z, normals, f_dc, f_rest (SH 3), opacity, scales, rots


def synthetic(n: int, seed: int = 0) -> Gaussians:
    rng = np.random.default_rng(seed)
    quats = rng.standard_normal((n, 4)).astype(np.float32)
    return Gaussians(
        means=rng.uniform(-5, 5, (n, 3)).astype(np.float32),
        log_scales=rng.uniform(-6, -2, (n, 3)).astype(np.float32),
        quats=quats,
        opacity_logits=rng.standard_normal(n).astype(np.float32),
        sh=(0.1 * rng.standard_normal((n, 16, 3))).astype(np.float32),
    )


def timed(fn, repeats: int) -> list[float]:  # noqa: ANN001
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--gigabytes", type=float, default=1.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--dir", default=tempfile.gettempdir())
    args = parser.parse_args()
    n = int(args.gigabytes * 1e9 / ROW_BYTES)
    path = Path(args.dir) / f"bench_{n}.ply"
    if not path.is_file():
        write_ply(path, synthetic(n))
    size_mb = path.stat().st_size / 1e6
    print(f"{path.name}: {n} Gaussians, SH degree 3, {size_mb:.0f} MB")
    ours = timed(lambda: read_ply(path, max_gaussians=n), args.repeats)
    print(f"ours (scene.ply.read_ply):   median {statistics.median(ours):.2f} s  "
          f"({size_mb / statistics.median(ours):.0f} MB/s)  runs {[round(t, 2) for t in ours]}")  # fmt: skip
    try:
        import gsply
    except ImportError:
        print("gsply not installed; pip install gsply to compare")
        return
    first = timed(lambda: gsply.plyread(str(path)), 1)[0]
    theirs = timed(lambda: gsply.plyread(str(path)), args.repeats)
    print(f"gsply {gsply.__version__} plyread:         median {statistics.median(theirs):.2f} s  "
          f"({size_mb / statistics.median(theirs):.0f} MB/s)  runs {[round(t, 2) for t in theirs]}; "
          f"first call in a process {first:.2f} s")  # fmt: skip
    print(f"ratio ours / gsply: {statistics.median(ours) / statistics.median(theirs):.2f}")


if __name__ == "__main__":
    main()
