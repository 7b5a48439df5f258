"""Benchmark: load/save a 1M-Gaussian SH-degree-3 binary splat (INRIA layout, 62 floats a row).

Prints the median of repeated reads and writes, and the same load done with plyfile
(`PlyData.read` without memory-mapping, then gathering the columns into the same arrays), so the
custom reader's speed is checked against the library baseline. Run by hand:

    .venv/bin/python bench/bench_ply_load.py [--n 1000000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from plyfile import PlyData

from bayesian_fields_core.scene.ply import read_ply, read_ply_header, write_ply
from bayesian_fields_core.scene.types import Gaussians


def make_gaussians(n: int, seed: int = 0) -> Gaussians:
    rng = np.random.default_rng(seed)
    f = np.float32
    return Gaussians(
        means=rng.normal(size=(n, 3)).astype(f),
        log_scales=rng.normal(size=(n, 3)).astype(f),
        quats=rng.normal(size=(n, 4)).astype(f),
        opacity_logits=rng.normal(size=n).astype(f),
        sh=rng.normal(size=(n, 16, 3)).astype(f),
        extra={k: rng.normal(size=n).astype(f) for k in ("nx", "ny", "nz")},
    )


def plyfile_load(path: Path) -> Gaussians:
    """The same arrays through plyfile: the baseline a hand-written reader must beat or match."""
    v = PlyData.read(str(path))["vertex"].data  # default memory-mapped read; mmap=False is ~100x slower

    def cols(names: list[str]) -> np.ndarray:
        return np.stack([v[n] for n in names], axis=1).astype(np.float32)

    n = len(v)
    rest = cols([f"f_rest_{i}" for i in range(45)]).reshape(n, 3, 15).transpose(0, 2, 1)
    sh = np.concatenate([cols(["f_dc_0", "f_dc_1", "f_dc_2"])[:, None, :], rest], axis=1)
    return Gaussians(
        means=cols(["x", "y", "z"]),
        log_scales=cols(["scale_0", "scale_1", "scale_2"]),
        quats=cols(["rot_0", "rot_1", "rot_2", "rot_3"]),
        opacity_logits=np.asarray(v["opacity"], np.float32),
        sh=sh,
        extra={k: np.asarray(v[k]) for k in ("nx", "ny", "nz")},
    )


def median_seconds(fn: Callable[[], object], repeats: int) -> tuple[float, list[float]]:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    g = make_gaussians(args.n)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.ply"
        write_med, write_all = median_seconds(lambda: write_ply(path, g), max(3, args.repeats // 2))
        size_mb = path.stat().st_size / 1e6
        read_med, read_all = median_seconds(lambda: read_ply(path), args.repeats)
        header_med, _ = median_seconds(lambda: read_ply_header(path), args.repeats)
        base_med, base_all = median_seconds(lambda: plyfile_load(path), args.repeats)
        ours, theirs = read_ply(path), plyfile_load(path)
        assert ours.sh.tobytes() == theirs.sh.tobytes() == g.sh.tobytes(), "readers disagree"

    print(f"splat: {args.n} Gaussians, SH degree 3, {size_mb:.1f} MB binary little-endian")
    print(f"write_ply        median {write_med:.3f} s  ({', '.join(f'{t:.3f}' for t in write_all)})")
    print(f"read_ply         median {read_med:.3f} s  ({', '.join(f'{t:.3f}' for t in read_all)})")
    print(f"read_ply_header  median {header_med * 1e3:.3f} ms")
    print(f"plyfile baseline median {base_med:.3f} s  ({', '.join(f'{t:.3f}' for t in base_all)})")
    print(f"read_ply speed-up over plyfile: {base_med / read_med:.2f}x; {size_mb / read_med:.0f} MB/s")


if __name__ == "__main__":
    main()
