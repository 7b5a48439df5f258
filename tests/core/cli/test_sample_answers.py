"""The demo's first answers against the sample's ground truth (issue 23, item 5).

`bfields run samples/tabletop` is what a new user runs first, and the README shows its table; this
pins down which of the sample's 8 tasks the full method answers right with the embedded
defaults, so a change to the method that moves the count (for better or worse) has to say so
here and in the README. A present task is right when its first answer is a strict detection of
one of its GT objects (Clio's Strict-osR: each box contains the other's centre); the absent
task ("pick up the red lamp") is right when it is answered "not found".
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from bayesian_fields_core.cli.main import main
from bayesian_fields_core.eval.box_iou import obb_contains_centroid
from bayesian_fields_core.eval.synthetic import load_ground_truth
from bayesian_fields_core.geometry.obb import OrientedBox
from bayesian_fields_core.results.colours import rank_colour
from bayesian_fields_core.results.reader import read_result

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "tabletop"

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


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`bfields run samples/tabletop` at the defaults, as the README runs it (once per module)."""
    tmp = tmp_path_factory.mktemp("demo")
    out = tmp / "out"
    args = ["run", str(SAMPLE), "--out", str(out), "--cache-dir", str(tmp / "cache"), "-q"]
    assert main(args) == 0
    return out


@pytest.mark.slow
def test_demo_first_answers_against_the_sample_ground_truth(demo: Path) -> None:
    right = first_answers_right(demo)
    assert len(right) == 8
    assert {task for task, ok in right.items() if ok} == RIGHT_TODAY, right


DOCS = SAMPLE.parents[1] / "docs"
SHEET = DOCS / "previews-contact-sheet.png"
SHEET_FINGERPRINT = DOCS / "previews-contact-sheet.json"
UPDATE_DOCS = "BFIELDS_UPDATE_DOCS_IMAGES"
"""Set to 1 to rewrite the README's contact sheet and its fingerprint from the demo run."""
MOVED_PIXELS = 0.005
"""Share of the sheet's pixels allowed to differ by more than PIXEL_TOLERANCE levels from the
committed picture: a re-render on another CPU moves a few edge pixels; a stale sheet (other views,
colours, selections) moves about 5 % (measured against the sheet of issue 31's time)."""
PIXEL_TOLERANCE = 40


def sheet_fingerprint(out: Path) -> dict[str, object]:
    """What the contact sheet shows, as data: per task its ranked object ids (or not found),
    and the rank colours of the legend. A pixel tolerance cannot tell object 26 from 28; this can."""
    result = read_result(out)
    tasks = [
        {"task": task, "objects": [o.object_id for o in result.selections.get(task, [])]}
        for task in result.tasks
    ]
    colours = ["#" + "".join(f"{round(float(c) * 255):02x}" for c in rank_colour(r)) for r in range(5)]
    return {"tasks": tasks, "rank_colours": colours}


@pytest.mark.slow
def test_the_readme_contact_sheet_is_the_current_demo(demo: Path) -> None:
    """The README's picture is this run's `previews/contact_sheet.png`. When the method, the
    previews or the sample change, regenerate it: BFIELDS_UPDATE_DOCS_IMAGES=1 pytest <this test>."""
    made = demo / "result" / "previews" / "contact_sheet.png"
    fingerprint = sheet_fingerprint(demo)
    if os.environ.get(UPDATE_DOCS) == "1":
        shutil.copyfile(made, SHEET)
        SHEET_FINGERPRINT.write_text(json.dumps(fingerprint, indent=1) + "\n")
    assert json.loads(SHEET_FINGERPRINT.read_text()) == fingerprint, f"stale: run with {UPDATE_DOCS}=1"
    committed = np.asarray(Image.open(SHEET).convert("RGB"), dtype=np.int16)
    current = np.asarray(Image.open(made).convert("RGB"), dtype=np.int16)
    assert committed.shape == current.shape, f"stale: run with {UPDATE_DOCS}=1"
    moved = float((np.abs(committed - current).max(axis=-1) > PIXEL_TOLERANCE).mean())
    assert moved < MOVED_PIXELS, f"{100 * moved:.1f}% of the pixels changed: run with {UPDATE_DOCS}=1"
