"""A stage's report as the attributes of its trace span: the counts a reader of a trace looks for.

The service's worker and `bfields run --trace` both open one span per stage and annotate it from
the stage's report (its marker), so the two traces say the same things under the same names:
``bfields.frames``, ``bfields.masks``, ``bfields.gaussians``, ``bfields.objects``, ... Only the
report's scalars are taken, and the one level of its ``counts`` mapping (the clustering's
primitives, objects, ...); timings by step and nested records (the likelihood, the scene scale)
stay in the report. Pure and dependency-free, so the library keeps no tracing client.
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping
from typing import Any

#: Prefix of every attribute the project sets on a span.
PREFIX = "bfields."

#: Nested report mappings whose scalar entries become attributes too.
FLATTENED = ("counts",)


def stage_attributes(stage: str, report: Mapping[str, Any]) -> dict[str, str | int | float | bool]:
    """``{"bfields.stage": stage, "bfields.<key>": value}`` for the report's scalar entries
    (str, int, float, bool) and those of its `FLATTENED` mappings."""
    out: dict[str, str | int | float | bool] = {PREFIX + "stage": stage}
    items = list(report.items())
    for name in FLATTENED:
        nested = report.get(name)
        if isinstance(nested, Mapping):
            items += list(nested.items())
    for key, value in items:
        if isinstance(value, str | bool):
            out[PREFIX + str(key)] = value
        elif isinstance(value, numbers.Integral):  # numpy integers too
            out[PREFIX + str(key)] = int(value)
        elif isinstance(value, numbers.Real):
            out[PREFIX + str(key)] = float(value)
    return out
