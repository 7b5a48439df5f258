"""The demo's first answers against the sample's ground truth (issue 23, item 5).

`bfields run samples/tabletop` is what a new user runs first, and the README shows its table; this
pins down which of the sample's 8 tasks the full method answers right with the embedded
defaults, so a change to the method that moves the count (for better or worse) has to say so
here and in the README. A present task is right when its first answer is a strict detection of
one of its GT objects (Clio's Strict-osR: each box contains the other's centre); the absent
task ("pick up the red lamp") is right when it is answered "not found".
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bayesian_fields_core.cli.main import main
from bayesian_fields_core.eval.box_iou import obb_contains_centroid
from bayesian_fields_core.eval.synthetic import load_ground_truth
from bayesian_fields_core.geometry.obb import OrientedBox
from bayesian_fields_core.results.reader import read_result

SAMPLE = Path(__file__).resolve().parents[2] / "samples" / "tabletop"

RIGHT_TODAY = {
    "get the orange cone",
    "pick up the orange mug",
    "get the cyan cube",
    "get the cyan sphere",
    "move all the orange things",
    "move all the cyan things",
    "pick up the red lamp",
}
"""Tasks the full method answers right at the defaults: 7 of 8 since issue 23's per-view
conditionals and fitted "not found" threshold (2 of 8 before: the orange cone and the orange mug
were one object, 11, joined by the AIB at a relative cost of ~2e-6 because both sides were
saturated on "move all the orange things"; `bench/merge_mechanism.py` has the mechanism). Still
wrong: "get the purple cones", whose first answer's box is not a Strict-osR match for either
purple cone (each box must contain the other's centre)."""


def first_answers_right(out: Path) -> dict[str, bool]:
    """Per task of the sample: whether the run's first answer is right (see the module doc)."""
    result = read_result(out)
    gt = load_ground_truth(SAMPLE)
    right = {}
    for task in gt.tasks:
        answers = result.selections.get(task.text, [])
        if task.granularity == "absent" or not task.objects:
            right[task.text] = not answers
            continue
        if not answers:
            right[task.text] = False
            continue
        box = answers[0].capture_box or answers[0].box  # GT lives in the cameras' frame
        right[task.text] = any(
            obb_contains_centroid(box, gt_box) and obb_contains_centroid(gt_box, box)
            for gt_box in (OrientedBox(o.center, o.rotation, o.extents) for o in task.objects)
        )
    return right


@pytest.mark.slow
def test_demo_first_answers_against_the_sample_ground_truth(tmp_path: Path) -> None:
    out = tmp_path / "out"
    args = ["run", str(SAMPLE), "--out", str(out), "--cache-dir", str(tmp_path / "cache"), "-q"]
    assert main(args) == 0
    right = first_answers_right(out)
    assert len(right) == 8
    assert {task for task, ok in right.items() if ok} == RIGHT_TODAY, right
