"""`bfields run` says what it is doing: "loading models" (and which), "compiling kernels" when the
numba kernels are not cached, stage clocks that start with the stage, `-q` without third-party
progress bars or chatter (transformers' "Loading weights"), `-v` with cache hits and misses, model
load times and per-stage timings.

One run of the real CLI in a subprocess (a fresh interpreter, so the third-party switches act
before those libraries are imported, and an empty numba cache) on the small pipeline scene; the
other checks run `cli.main` in process.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from bayesian_fields_core.cli.main import main
from bayesian_fields_core.job.factories import local_job
from bayesian_fields_core.job.pipeline import run_job
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import load_models
from tests.core.conftest import N_FRAMES

# Slow (the inner loop leaves it out): its fixtures took 60 s to set up here (--durations).
pytestmark = pytest.mark.slow

HF_BAR = "Loading weights"  # transformers' tqdm bar, printed on every CLIPModel load
# Small and quick: the alignment check renders frames, the result writer renders previews.
CHEAP = ["--param", "alignment_check=false", "--param", "previews=false", "--param", "export_ply=false"]


def _run_args(scene_dir: Path, profile_yaml: Path, cache: Path) -> list[str]:
    return [
        "run",
        str(scene_dir),
        "--task",
        "red chair",
        "--profile",
        str(profile_yaml),
        "--cache-dir",
        str(cache),
        *CHEAP,
    ]


def _bfields(args: list[str], numba_cache: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(numba_cache), "COLUMNS": "200"}
    return subprocess.run(
        [sys.executable, "-m", "bayesian_fields_core.cli.main", *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )


@pytest.fixture(scope="module")
def first_run(
    scene_dir: Path, profile_yaml: Path, tmp_path_factory: pytest.TempPathFactory
) -> dict[str, Any]:
    """One real `bfields run --json` in a fresh interpreter, with empty perception and numba caches."""
    root = tmp_path_factory.mktemp("narration")
    args = [*_run_args(scene_dir, profile_yaml, root / "cache"), "--out", str(root / "a"), "--json"]
    done = _bfields(args, root / "numba")
    assert done.returncode == 0, done.stderr
    return {"done": done, "cache": root / "cache"}


def test_it_says_which_models_it_loads_and_that_it_compiles(first_run: dict[str, Any]) -> None:
    done = first_run["done"]
    assert json.loads(done.stdout)["tasks"] == ["red chair"]
    lines = done.stderr.splitlines()
    assert "loading models: segmenter classical, encoder hf_clip (tiny-clip, cpu)" in lines
    assert "compiling kernels (first run only, ~10 s)" in lines
    # Announced before the work it announces: before the bars of those stages end.
    assert lines.index("compiling kernels (first run only, ~10 s)") < next(
        i for i, line in enumerate(lines) if line.startswith("cluster ")
    )
    # transformers' bar is off (by its environment switch: this interpreter imported it after).
    assert HF_BAR not in done.stderr and "debug:" not in done.stderr


def test_verbose_and_quiet(
    scene_dir: Path, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """In process, where transformers is imported already: the switches use its own API."""
    args = _run_args(scene_dir, profile_yaml, tmp_path / "cache")
    assert main([*args, "--out", str(tmp_path / "a"), "-v"]) == 0
    err = capsys.readouterr().err
    assert f"debug: perception cache: 0 hit(s), {N_FRAMES} miss(es)" in err
    assert f"debug: visibility cache: 0 hit(s), {N_FRAMES} miss(es)" in err
    assert "debug: segmenter classical loaded in " in err
    assert "debug: encoder hf_clip (tiny-clip, cpu) loaded in " in err
    assert "debug: numba kernels: cache hit" in err
    for stage in ("perceive", "fuse", "cluster"):
        assert f"debug: stage {stage}: " in err
    assert "segment " in err and "aib " in err  # the steps inside the stages
    assert HF_BAR in err  # -v lets third-party libraries talk again

    assert main([*args, "--out", str(tmp_path / "b"), "-v"]) == 0
    err = capsys.readouterr().err
    assert f"debug: perception cache: {N_FRAMES} hit(s), 0 miss(es)" in err
    assert f"debug: visibility cache: {N_FRAMES} hit(s), 0 miss(es)" in err

    assert main([*args, "--out", str(tmp_path / "c"), "-q", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["tasks"] == ["red chair"]
    # The encoder still loads (for the task texts), silently; nothing but the check's line.
    assert err.strip() == "alignment check: off", err


def test_each_stage_clock_starts_before_its_model_loading(
    first_run: dict[str, Any], scene_dir: Path, profile_yaml: Path, tmp_path: Path
) -> None:
    """The CLI's bar for a stage starts on the stage's first progress call: it must come before
    anything the stage does, model loading included (it used to come after the first frame, so
    fuse's bar read 0:00:00 while fuse loaded CLIP)."""
    events: list[tuple[str, ...]] = []

    class Recorder(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            events.append(("log", record.getMessage()))

    lib = logging.getLogger("bayesian_fields_core")
    handler, level = Recorder(), lib.level
    lib.addHandler(handler)
    lib.setLevel(logging.INFO)
    try:
        job = local_job(
            scene_dir,
            tmp_path / "out",
            first_run["cache"],  # perception cached: the encoder loads inside fuse
            ["red chair"],
            PipelineParams(alignment_check=False, previews=False, export_ply=False),
            load_models(profile_yaml),
            progress=lambda stage, fraction: events.append(("progress", stage, str(fraction))),
        )
        run_job(job, force=True)
    finally:
        lib.removeHandler(handler)
        lib.setLevel(level)
    loading = events.index(("log", "loading models: encoder hf_clip (tiny-clip, cpu)"))
    fuse_events = [i for i, e in enumerate(events) if e[:2] == ("progress", "fuse")]
    assert events[fuse_events[0]] == ("progress", "fuse", "0.0") and fuse_events[0] < loading
    for stage in ("perceive", "fuse", "cluster"):
        first = next(e for e in events if e[:2] == ("progress", stage))
        assert first == ("progress", stage, "0.0")
