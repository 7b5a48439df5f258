"""Labelled scores for calibration: the labelling rule by hand, then the command on the sample scene."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.cli.main import main
from bayesian_fields_core.eval.calibration.ground_truth import label_masks

SAMPLE = Path(__file__).resolve().parents[2] / "samples" / "tabletop"


def test_label_masks_by_hand() -> None:
    # Gaussians 0-3 belong to task 0's object, 4-5 to task 1's; Gaussian 6 to nothing.
    relevant = np.zeros((7, 2), dtype=bool)
    relevant[:4, 0] = True
    relevant[4:6, 1] = True
    # mask 0 sees 0,1,2,6 (3/4 task 0); mask 1 sees 3,4 (1/2 each); mask 2 sees 6; mask 3 nothing.
    gaussian_ids = np.array([0, 1, 2, 6, 3, 4, 6])
    mask_ids = np.array([0, 0, 0, 0, 1, 1, 2])
    pos, neg = label_masks(gaussian_ids, mask_ids, 4, relevant, positive_overlap=0.6)
    np.testing.assert_array_equal(pos, [[True, False], [False, False], [False, False], [False, False]])
    np.testing.assert_array_equal(neg, [[False, True], [False, False], [True, True], [False, False]])
    pos_half, _ = label_masks(gaussian_ids, mask_ids, 4, relevant, positive_overlap=0.5)
    assert pos_half[1].tolist() == [True, True]


def test_calibrate_from_the_sample_scene_separates_the_classes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "cal.json"
    assert main(["calibrate", "--scene", str(SAMPLE), "--max-frames", "4", "--out", str(out)]) == 0
    assert "positive" in capsys.readouterr().out
    cal = json.loads(out.read_text())
    assert cal["model_id"].startswith("tiny-clip@")
    assert cal["num_positive"] > 10 and cal["num_negative"] > cal["num_positive"]
    # The tiny CLIP scores relevant masks well above irrelevant ones.
    assert cal["mu1"] - cal["mu0"] > 0.2
    assert 0 < cal["s"] < 1


def test_calibrate_rejects_a_scene_without_ground_truth(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["calibrate", "--scene", str(tmp_path), "--out", str(tmp_path / "c.json")]) == 2
    assert "gt.json" in capsys.readouterr().err
    assert not (tmp_path / "c.json").exists()


def test_negative_sources_differ_as_documented(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The paper's recipe (tasks with no object in the scene) against every unrelated pair."""
    counts = {}
    for source in ("absent", "unrelated"):
        out = tmp_path / f"{source}.json"
        args = [
            "calibrate",
            "--scene",
            str(SAMPLE),
            "--max-frames",
            "3",
            "--negatives",
            source,
            "--out",
            str(out),
        ]
        assert main(args) == 0
        counts[source] = json.loads(out.read_text())
    # The sample has one absent task ("pick up the red lamp"), so its negatives are one score per
    # observed mask; the unrelated pairs include that task and every other one.
    assert counts["absent"]["num_positive"] == counts["unrelated"]["num_positive"]
    assert 0 < counts["absent"]["num_negative"] < counts["unrelated"]["num_negative"]
