"""Compare two tiny-CLIP folders on the same held-out crops (seeds the training never used).

Why: a retrained tiny CLIP replaces the committed one only if it reads the plain vocabulary as
well as before and reads labels better; both are measured here on one fixed crop set, through the
production encoder (`HFClipEncoder`), so the figures are comparable across models and sessions.

Usage: ``.venv/bin/python bench/compare_tiny_clip.py OLD_DIR NEW_DIR [--objects 200]``
(OLD_DIR e.g. from ``git archive HEAD~1 bayesian_fields_core/models/tiny-clip``). Prints, per
model: canonical top-1 on plain object and scene crops (the test's measure), on striped objects
and textured scenes (the capture suite's look), on label-bearing crops, and the label measures
of `eval.clip_quality.LabelReading`.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bayesian_fields_core.eval.clip_quality import canonical_top1, label_reading
from bayesian_fields_core.eval.synthetic.crops import object_crops, scene_crops
from bayesian_fields_core.perception.hf_clip import HFClipEncoder

HELD_OUT_SEED = 987_654  # the test's seed; training uses seeds 0 and 1000


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("models", nargs="+", type=Path, help="tiny-CLIP folders to compare")
    p.add_argument("--objects", type=int, default=200, help="single objects per crop set")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    rng = np.random.default_rng(HELD_OUT_SEED)
    plain = object_crops(rng, args.objects, views_per_object=2) + scene_crops(rng, 2, 6, min_area=150)
    labelled = object_crops(np.random.default_rng(HELD_OUT_SEED + 7), args.objects, 4, label_share=1.0)
    striped = object_crops(np.random.default_rng(HELD_OUT_SEED + 8), args.objects, 2, stripe_share=1.0)
    striped += scene_crops(np.random.default_rng(HELD_OUT_SEED + 9), 2, 6, min_area=150, textured_share=1.0)
    shown = [c for c in labelled if c.label is not None]
    print(
        f"held-out crops: {len(plain)} plain, {len(striped)} striped / checkered, {len(labelled)} of "
        f"labelled objects ({len(shown)} show their label), made in {time.perf_counter() - t0:.0f} s"
    )
    header = ("top-1 plain", "top-1 striped", "top-1 labelled", "label top-1", "label AUC")
    print(f"{'model':40s} " + " ".join(f"{h:>14s}" for h in header))
    for folder in args.models:
        enc = HFClipEncoder(folder)
        reading = label_reading(enc, labelled)
        row = (
            canonical_top1(enc, plain),
            canonical_top1(enc, striped),
            canonical_top1(enc, labelled),
            reading.label_top1,
            reading.label_auc,
        )
        print(f"{str(folder)[-40:]:40s} " + " ".join(f"{v:14.3f}" for v in row))


if __name__ == "__main__":
    main()
