"""How well an image/text encoder reads the synthetic vocabulary: held-out measures shared by the
tiny CLIP's training script, its test and ``bench/compare_tiny_clip.py``.

Why here: the committed tiny CLIP is replaced only when a retrained one is at least as good on
the same held-out crops, so the measures must be one function, not three copies.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Protocol

import numpy as np

from bayesian_fields_core.eval.synthetic.crops import LabelledCrop
from bayesian_fields_core.eval.synthetic.tasks import label_task_text
from bayesian_fields_core.eval.vocabulary import LABELLED_KINDS, canonical_captions, label_colours


class TextImageEncoder(Protocol):
    def encode_images(self, images: list[np.ndarray]) -> np.ndarray: ...
    def encode_texts(self, texts: list[str]) -> np.ndarray: ...


def canonical_top1(encoder: TextImageEncoder, crops: list[LabelledCrop]) -> float:
    """Share of crops whose own canonical caption ("red cube", "table") scores first among all
    52 canonical captions (a labelled cube is still a "red cube")."""
    names = canonical_captions()
    truth = np.array([names.index(f"{c.colour} {c.kind}" if c.colour else c.kind) for c in crops])
    scores = encoder.encode_images([c.image for c in crops]) @ encoder.encode_texts(names).T
    return float(np.mean(scores.argmax(axis=1) == truth))


@dataclass(frozen=True)
class LabelReading:
    """label_crops: crops that show a label; label_top1: the share of them whose task naming the
    right label ("get the red cube with the blue label") outscores the six naming another label;
    label_auc: over crops of one colour and kind and the tasks naming a label on them, the
    probability that a crop showing that label outscores one that does not (the labelled object
    seen from behind, or a look-alike without a label): what a label task needs to pick the right
    instance. 0.5 is chance for the AUC, 1/6 for the top-1."""

    label_crops: int
    label_top1: float
    label_auc: float

    def as_dict(self) -> dict[str, float | int]:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in asdict(self).items()}


def label_reading(encoder: TextImageEncoder, crops: list[LabelledCrop]) -> LabelReading:
    """Label measures (see LabelReading) over the crops of labellable kinds among `crops`."""
    crops = [c for c in crops if c.colour is not None and c.kind in LABELLED_KINDS]
    groups: dict[tuple[str, str], list[int]] = {}
    for i, c in enumerate(crops):
        assert c.colour is not None
        groups.setdefault((c.colour, c.kind), []).append(i)
    img = encoder.encode_images([c.image for c in crops]) if crops else np.zeros((0, 1))
    positives: list[float] = []
    negatives: list[float] = []
    hits = 0
    for (colour, kind), rows in groups.items():
        labels = label_colours(colour)
        txt = encoder.encode_texts([label_task_text(colour, kind, lab) for lab in labels])
        scores = img[rows] @ txt.T  # (crops of this colour and kind, 6 labels)
        for r, row in zip(rows, scores, strict=True):
            shown = crops[r].label
            if shown is not None:
                hits += int(labels[int(np.argmax(row))] == shown)
                positives.append(float(row[labels.index(shown)]))
        for j, lab in enumerate(labels):
            negatives += [float(scores[i, j]) for i, r in enumerate(rows) if crops[r].label != lab]
    p, n = np.array(positives), np.array(negatives)
    auc = float(np.mean(p[:, None] > n[None, :])) if len(p) and len(n) else float("nan")
    return LabelReading(len(p), hits / len(p) if len(p) else float("nan"), auc)
