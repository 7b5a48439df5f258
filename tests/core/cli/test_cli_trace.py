"""`bfields run --trace FILE`: the run's trace as JSON lines, one trace whose spans all resolve
their parents, the run at the root, each stage with its report's counts; a run refused part-way
leaves the spans that ended, the failing ones marked ERROR."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bayesian_fields_core.cli.main import main
from tests.core.conftest import N_FRAMES
from tests.support.scene_transforms import copy_scene, move_splat

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "tabletop"


def _spans(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def _run(scene: Path, tmp_path: Path, profile_yaml: Path, trace: Path) -> int:
    return main(["run", str(scene), "--out", str(tmp_path / "out"), "--cache-dir", str(tmp_path / "cache"),
                 "--profile", str(profile_yaml), "-q", "--task", "red chair", "--trace", str(trace)])  # fmt: skip


@pytest.mark.slow
def test_run_writes_its_trace(scene_dir: Path, profile_yaml: Path, tmp_path: Path) -> None:
    trace = tmp_path / "traces" / "run.jsonl"
    assert _run(scene_dir, tmp_path, profile_yaml, trace) == 0
    spans = _spans(trace)
    assert len({s["trace_id"] for s in spans}) == 1
    by_id = {s["span_id"]: s for s in spans}
    (root,) = [s for s in spans if s["parent_id"] is None]
    assert root["name"] == "bfields run" and root["attributes"]["bfields.tasks"] == 1
    assert all(s["parent_id"] in by_id for s in spans if s is not root)
    assert all(s["start_ns"] <= s["end_ns"] and s["status"] == "UNSET" for s in spans)
    names = [s["name"] for s in sorted(spans, key=lambda s: s["start_ns"])]
    assert names == [
        "bfields run",
        "load models",
        "check inputs",
        "stage perceive",
        "stage fuse",
        "stage cluster",
    ]
    stages = {
        s["attributes"]["bfields.stage"]: s["attributes"] for s in spans if s["name"].startswith("stage ")
    }
    assert stages["perceive"]["bfields.frames"] == N_FRAMES
    assert stages["fuse"]["bfields.masks"] > 0 and stages["fuse"]["bfields.gaussians"] > 0
    assert stages["cluster"]["bfields.objects"] >= 1
    # the run's own report agrees with its spans
    report = json.loads((tmp_path / "out" / "result" / "summary.json").read_text())
    assert report["scene"]["num_gaussians"] == stages["fuse"]["bfields.gaussians"]


@pytest.mark.slow
def test_a_refused_run_leaves_its_error_in_the_trace(
    profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = move_splat(copy_scene(SAMPLE, tmp_path / "moved"), scale=0.5, shift=(0.4, 0.0, 0.0))
    trace = tmp_path / "run.jsonl"
    assert _run(scene, tmp_path, profile_yaml, trace) == 2
    assert "alignment:" in capsys.readouterr().err
    spans = {s["name"]: s for s in _spans(trace)}
    assert set(spans) == {"bfields run", "load models", "check inputs"}
    assert spans["check inputs"]["status"] == spans["bfields run"]["status"] == "ERROR"
    assert spans["check inputs"]["attributes"]["exception.type"] == "InputError"
    assert spans["load models"]["status"] == "UNSET"
