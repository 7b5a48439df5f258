"""The streamed splat check: same verdicts as `read_ply`, in memory bounded by the chunk size."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene import ply_scan
from bayesian_fields_core.scene.ply import read_ply, write_ply
from bayesian_fields_core.scene.ply_scan import sample_index, scan_ply
from bayesian_fields_core.scene.sanity import splat_warnings
from bayesian_fields_core.scene.types import Gaussians


def splat(n: int, *, degree: int = 3, extras: int = 20, seed: int = 0) -> Gaussians:
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2
    return Gaussians(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        log_scales=rng.uniform(-6, -3, size=(n, 3)).astype(np.float32),
        quats=rng.normal(size=(n, 4)).astype(np.float32) + np.float32(2),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        sh=rng.normal(size=(n, k, 3)).astype(np.float32),
        extra={f"extra_{i}": rng.normal(size=n).astype(np.float32) for i in range(extras)},
    )


@pytest.fixture
def small_chunks(monkeypatch: pytest.MonkeyPatch) -> None:
    """Chunks of a few rows, so chunk boundaries fall everywhere in small files."""
    monkeypatch.setattr(ply_scan, "CHUNK_BYTES", 7 * 300)


def _verdict(fn, path: Path) -> str:  # noqa: ANN001
    try:
        fn(path)
    except InputError as exc:
        return str(exc)
    return "ok"


@pytest.mark.usefixtures("small_chunks")
@pytest.mark.parametrize(
    "damage",
    ["none", "nan_mean", "inf_rest", "nan_scale_and_opacity", "zero_quat", "huge_scale", "far"],
)
def test_the_scan_refuses_what_read_ply_refuses_with_the_same_message(damage: str, tmp_path: Path) -> None:
    g = splat(500)
    rows = [3, 177, 499]
    if damage == "nan_mean":
        g.means[rows, 1] = np.nan
    elif damage == "inf_rest":
        g.sh[rows, 5, 2] = np.inf
    elif damage == "nan_scale_and_opacity":
        g.log_scales[rows, 0] = np.nan
        g.opacity_logits[rows[:2]] = np.nan
    elif damage == "zero_quat":
        g.quats[rows] = 0
    elif damage == "huge_scale":
        g.log_scales[rows, 2] = 50
    elif damage == "far":
        g.means[rows, 0] = 1e9
    path = tmp_path / "s.ply"
    write_ply(path, g)
    expected = _verdict(read_ply, path)
    assert _verdict(lambda p: scan_ply(p, sample_size=100), path) == expected
    assert (expected == "ok") == (damage == "none")


@pytest.mark.usefixtures("small_chunks")
@pytest.mark.parametrize("n", [50, 999])
def test_the_sample_is_the_alignment_checks_sample(n: int, tmp_path: Path) -> None:
    path = tmp_path / "s.ply"
    write_ply(path, splat(n, degree=1, extras=3))
    whole = read_ply(path)
    scan = scan_ply(path, sample_size=200)
    index = sample_index(n, 200)
    assert scan.count == n and scan.sh_degree == 1
    np.testing.assert_array_equal(scan.sample.means, whole.means[index])
    np.testing.assert_array_equal(scan.sample.opacity_logits, whole.opacity_logits[index])
    np.testing.assert_array_equal(scan.sample.sh, whole.sh[index])
    if n <= 200:  # the warnings' extent is exact when the sample is the whole splat
        assert scan.warnings == splat_warnings(whole)


@pytest.mark.usefixtures("small_chunks")
def test_the_warnings_match_on_a_splat_that_warns(tmp_path: Path) -> None:
    g = splat(150)
    g.opacity_logits[:] = -20  # invisible
    g.log_scales[:10] = 3  # wider than the scene
    path = tmp_path / "s.ply"
    write_ply(path, g)
    scan = scan_ply(path, sample_size=1000)
    assert scan.warnings == splat_warnings(read_ply(path)) and len(scan.warnings) == 2


@pytest.mark.slow
def test_peak_memory_is_bounded_by_the_chunk_not_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """40 MB splat, 1 MB chunks: the scan's peak of traced allocations stays a few chunks, while
    `read_ply` holds more than the file."""
    monkeypatch.setattr(ply_scan, "CHUNK_BYTES", 1 << 20)
    path = tmp_path / "big.ply"
    write_ply(path, splat(130_000))
    size = path.stat().st_size
    assert size > 35e6

    def peak(fn) -> int:  # noqa: ANN001
        tracemalloc.start()
        try:
            fn()
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    scanned = peak(lambda: scan_ply(path, sample_size=2000))
    whole = peak(lambda: read_ply(path))
    assert scanned < 8 << 20, f"scan peak {scanned / 2**20:.1f} MiB for a {size / 2**20:.0f} MiB file"
    assert whole > size
