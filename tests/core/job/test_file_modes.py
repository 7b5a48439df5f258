"""Result files get the mode the umask gives any new file (issue 45): they were written through
`mkstemp` (0600) and renamed, so a robot process under another user or a web server could not read
a result. A real `bfields run` under umask 022 must leave only 0644 files, under 027 only 0640."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.cli.main import main
from bayesian_fields_core.job.store import LocalStore, put_array_blocks


@pytest.fixture
def umask() -> Iterator[object]:
    """Set the process umask for one test (`umask(0o027)`), restored afterwards."""
    before = os.umask(0o022)
    os.umask(before)
    yield lambda mask: os.umask(mask)
    os.umask(before)


def _modes(root: Path) -> dict[str, int]:
    return {
        p.relative_to(root).as_posix(): stat.S_IMODE(p.stat().st_mode) for p in root.rglob("*") if p.is_file()
    }


@pytest.mark.parametrize(("mask", "mode"), [(0o022, 0o644), (0o027, 0o640)])
def test_local_store_writes_with_the_umask_mode(mask: int, mode: int, umask, tmp_path: Path) -> None:
    umask(mask)
    store = LocalStore(tmp_path / "store")
    store.put_bytes("a/summary.json", b"{}")
    src = tmp_path / "src.bin"
    src.write_bytes(b"x")
    store.put_file("a/copy.bin", src)
    put_array_blocks(store, "a/arrays.npz", x=np.arange(10))
    assert _modes(tmp_path / "store") == {"a/summary.json": mode, "a/copy.bin": mode, "a/arrays.npz": mode}


@pytest.mark.slow
def test_a_run_leaves_result_files_readable_as_the_umask_says(
    scene_dir: Path, profile_yaml: Path, tmp_path: Path, umask, capsys: pytest.CaptureFixture[str]
) -> None:
    for mask, mode in [(0o022, 0o644), (0o027, 0o640)]:
        umask(mask)
        out = tmp_path / f"out-{mask:o}"
        args = ["run", str(scene_dir), "--out", str(out), "--cache-dir", str(tmp_path / "cache")]
        args += ["--profile", str(profile_yaml), "-q", "--task", "red chair", "--param", "max_frames=2"]
        assert main(args) == 0, capsys.readouterr().err
        modes = _modes(out)
        assert "result/summary.json" in modes and any(k.endswith(".bin") for k in modes), sorted(modes)
        assert any(k.startswith("stages/") for k in modes) and any("exports/" in k for k in modes), sorted(
            modes
        )
        wrong = {k: oct(m) for k, m in modes.items() if m != mode}
        assert not wrong, f"umask {mask:o}: expected {mode:o}, got {wrong}"
