"""Every run applies the 'not found' threshold stored with the model's calibration (issue 46): the
one source is the calibration file `bfields calibrate --scene` writes; `bfields run` (and the
service's workers, which build the same job) read it through the profile."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml

from bayesian_fields_core.cli.main import main
from bayesian_fields_core.perception.models import load_models
from bayesian_fields_core.results.reader import read_result


def _profile_with_threshold(profile: dict[str, Any], folder: Path, threshold: float | None) -> Path:
    """The test profile with its calibration moved to a file that carries `threshold`."""
    inline = profile["calibration"]
    base = folder / "base.yaml"
    base.write_text(yaml.safe_dump(profile), encoding="utf-8")
    model_id = str(load_models(str(base)).encoder.model_id)
    cal = {"model_id": model_id, "mu0": inline["mu0"], "mu1": inline["mu1"], "s": inline["s"]}
    (folder / "calibration.json").write_text(json.dumps(cal | {"answer_min_peak": threshold}))
    path = folder / "profile.yaml"
    path.write_text(yaml.safe_dump(profile | {"calibration": {"path": "calibration.json"}}), encoding="utf-8")
    return path


@pytest.mark.timeout(600)
def test_bfields_run_applies_the_calibrations_fitted_threshold(
    scene_dir: Path, profile: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cache = tmp_path / "cache"
    answered: dict[str, Any] = {}
    for threshold in (9.5, None):
        folder = tmp_path / f"t{threshold}"
        folder.mkdir()
        path = _profile_with_threshold(profile, folder, threshold)
        out = folder / "out"
        args = [
            "run",
            str(scene_dir),
            "--out",
            str(out),
            "--cache-dir",
            str(cache),
            "--profile",
            str(path),
            "-q",
        ]
        assert main([*args, "--task", "red chair", "--task", "blue cup"]) == 0
        capsys.readouterr()
        answered[str(threshold)] = read_result(out)
    # A threshold no best view reaches: every task "not found", and the run records it.
    high = answered["9.5"]
    assert high.parameters["answer_min_peak"] == 9.5
    assert set(high.not_found) == {"red chair", "blue cup"}
    assert all(nf.threshold == 9.5 for nf in high.not_found.values())
    # Without a fitted one the run falls back to the distribution threshold (not 9.5).
    assert answered["None"].parameters["answer_min_peak"] != 9.5
