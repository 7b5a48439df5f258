"""A stage report as span attributes: its scalars and its counts, prefixed; nothing nested."""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.job.span_attributes import stage_attributes


def test_scalars_and_counts_become_attributes() -> None:
    report = {
        "seconds": 1.5,
        "frames": 4,
        "masks": np.int64(77),
        "fusion_device": "cpu",
        "cached": False,
        "counts": {"primitives": 61, "objects": np.int32(51)},
        "timings": {"segment": 0.3},  # per-step timings stay in the report
        "likelihood": {"mu0": 0.1},
        "skipped": None,
        "frames_list": [1, 2],
    }
    got = stage_attributes("fuse", report)
    assert got == {
        "bfields.stage": "fuse",
        "bfields.seconds": 1.5,
        "bfields.frames": 4,
        "bfields.masks": 77,
        "bfields.fusion_device": "cpu",
        "bfields.cached": False,
        "bfields.primitives": 61,
        "bfields.objects": 51,
    }
    assert type(got["bfields.masks"]) is int and type(got["bfields.objects"]) is int  # JSON- and OTLP-ready
