"""The worker images compile the numba kernels at build time into NUMBA_CACHE_DIR; this runs the
same command and checks that the cache lands there and is what a second process loads, and that
compiling is announced only when it happens (`prepare_kernels`, which the cluster stage calls)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest


def _run(cache: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    return subprocess.run(
        [sys.executable, "-m", "bayesian_fields_core.objects.compile_kernels"],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )


@pytest.mark.slow
def test_kernels_compile_into_the_cache_dir_and_are_reused(tmp_path: Path) -> None:
    first = _run(tmp_path)
    assert first.returncode == 0, first.stderr
    assert "numba kernels ready" in first.stdout
    assert "compiling kernels (first run only" in first.stderr  # what `bfields run` prints too
    # Index files are named <module>.<function>-<line>.<python>.nbi.
    index = {p.name.split("-")[0] for p in tmp_path.rglob("*.nbi")}
    assert {"aib_kernel.greedy_merges", "edges._sweep", "edges._identical_rows"} <= index
    stamps = {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*.nbc")}
    second = _run(tmp_path)
    assert second.returncode == 0, second.stderr
    assert "compiling kernels" not in second.stderr and "ready in 0.0 s" in second.stdout
    # Loaded, not recompiled: no cached object was rewritten.
    assert {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*.nbc")} == stamps
